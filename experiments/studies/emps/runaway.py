"""Which EMPS PGNN seeds run away beyond the training window, and what their networks do there.

``python -m experiments.studies.emps.runaway [CONFIG] [--out DIR] [--rows I,J,...]`` fits the
PGNN rows of ``experiments/configs/emps_pgnn.yaml`` (default: its three rows at lambda = 0.01
and lambda = 0 on the paper's cost and lambda = 0.01 with weight decay, the row that the page
names as the remedy) on the measured training record, as ``clm-sim run`` does (the same seeds,
the same fits), and writes ``runaway.json`` and ``report.md``:

* per seed, the force rms (N) inside and beyond the window on both records, and the flag: a
  seed **runs away** where its force rms beyond the window, on either record, exceeds
  ``RUNAWAY`` times the LIP's there (an order of magnitude worse than a line in the features);
* per seed, its network: the output weights (largest |w_j|, and the sum of |w_j| against the
  rms of the network's force inside: units that cancel each other inside), and per unit its
  pre-activation's largest |z| inside the window and beyond it, so how far beyond the training
  data's hull each unit is evaluated;
* the window's coverage: per feature column (a, v, sign v, y) its range inside the window and
  beyond, in the network's scaled units.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

RUNAWAY = 10.0
COLUMNS = ("a", "v", "sign v", "y")


def _rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def seed_view(model, records) -> dict:
    """One fitted PGNN on the prepared records: its force error inside and beyond, its
    output weights and its units' pre-activations inside and beyond the window."""
    from experiments.studies.mechanism.units import pre_activations

    mlp = model.network_.mlp
    w_out = mlp.out.weight.detach().numpy()[0]
    train = records[0]
    z_in = pre_activations(model, train.phi[train.inside])
    z_out = np.vstack([pre_activations(model, r.phi[~r.inside]) for r in records])
    net_in = model.network(train.phi[train.inside])
    theta = np.array([model.theta_[k] for k in ("mass", "viscous", "coulomb", "stiffness")])
    err = {}
    for r in records:
        pred = r.phi @ theta + model.network(r.phi)
        err[r.name] = {"inside": _rms((r.target - pred)[r.inside]),
                       "outside": _rms((r.target - pred)[~r.inside])}
    zi, zo = np.max(np.abs(z_in), axis=0), np.max(np.abs(z_out), axis=0)
    return {"force_rms": err, "w_out_max": float(np.max(np.abs(w_out))),
            "w_out_sum": float(np.sum(np.abs(w_out))), "network_inside_rms": _rms(net_in),
            "units_z_inside": zi.tolist(), "units_z_beyond": zo.tolist(),
            "units_w_out": w_out.tolist(),
            "units_flat_inside": int(np.sum(zi > 3.0)),  # saturated on the window's samples
            "largest_unit_beyond_rms_n": float(max(
                _rms(w_out[j] * np.tanh(z_out[:, j])) for j in range(len(w_out))))}


def coverage(model, records) -> dict:
    """Per feature column, its range inside the window and beyond it (all records), in the
    network's scaled units ``(phi - mean)/std``."""
    mlp = model.network_.mlp
    mean, std = mlp.input_mean.numpy(), mlp.input_std.numpy()
    train = records[0]
    s_in = (train.phi[train.inside] - mean) / std
    s_out = (np.vstack([r.phi[~r.inside] for r in records]) - mean) / std
    return {c: {"inside": [float(s_in[:, k].min()), float(s_in[:, k].max())],
                "beyond": [float(s_out[:, k].min()), float(s_out[:, k].max())]}
            for k, c in enumerate(COLUMNS)}


def compute(config, progress=print) -> dict:
    from experiments.records import fit as record_fit
    recs = [("training", config.data.load("training"))]
    if config.data.validation is not None:
        recs.append(("validation", config.data.load("validation")))
    prepared = [record_fit.prepare(config, run, name) for name, run in recs]
    lip = record_fit.fit_lip(prepared[0])
    lip_err = {r.name: record_fit.force_rms(lip.predict(r.phi), r) for r in prepared}
    rows = record_fit.fit_rows(config, prepared, progress, lip)
    out = {"lip": lip_err, "rows": [], "runaway_factor": RUNAWAY}
    for row, models in rows:
        if row.kind != "pgnn":
            continue
        seeds = []
        for s, m in enumerate(models):
            v = seed_view(m, prepared)
            v["seed"] = s
            v["runaway"] = any(v["force_rms"][r.name]["outside"]
                               > RUNAWAY * lip_err[r.name]["outside"] for r in prepared)
            seeds.append(v)
        out["rows"].append({"label": row.label, "seeds": seeds,
                            "stops": [f.stop for f in row.fits],
                            "coverage": coverage(models[0], prepared)})
    return out


def report(s: dict) -> str:
    lip = s["lip"]
    out = ["# EMPS PGNN rows: which seeds run away beyond the window", "",
           f"A seed runs away where its force rms beyond the window exceeds "
           f"{s['runaway_factor']:g}× the LIP's (training {lip['training']['outside']:.3f} N"
           + (f", validation {lip['validation']['outside']:.3f} N" if "validation" in lip
              else "") + ") on either record.", "",
           "| row | seed | stop | training beyond [N] | validation beyond [N] | runs away | "
           "largest |w_out| | Σ|w_out| / network rms inside | units saturated inside | largest "
           "|z| inside | largest |z| beyond | largest unit's force beyond [N] |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in s["rows"]:
        for v, stop in zip(row["seeds"], row["stops"]):
            fr = v["force_rms"]
            out.append(f"| {row['label']} | {v['seed']} | {stop} | "
                       f"{fr['training']['outside']:.4g} | "
                       f"{fr.get('validation', {}).get('outside', float('nan')):.4g} | "
                       f"{'**yes**' if v['runaway'] else 'no'} | {v['w_out_max']:.3g} | "
                       f"{v['w_out_sum'] / v['network_inside_rms']:.3g} | "
                       f"{v['units_flat_inside']} | {max(v['units_z_inside']):.3g} | "
                       f"{max(v['units_z_beyond']):.3g} | "
                       f"{v['largest_unit_beyond_rms_n']:.4g} |")
    out += ["", "Per row: runaway seeds, and medians of the runaway and the other seeds:", ""]
    for row in s["rows"]:
        bad = [v for v in row["seeds"] if v["runaway"]]
        good = [v for v in row["seeds"] if not v["runaway"]]
        med = lambda vs, k: float(np.median([v[k] for v in vs])) if vs else float("nan")  # noqa
        zmax = lambda vs: float(np.median([max(v["units_z_beyond"]) for v in vs])) if vs \
            else float("nan")  # noqa: E731
        out.append(f"* {row['label']}: {len(bad)} of {len(row['seeds'])} run away (seeds "
                   f"{', '.join(str(v['seed']) for v in bad) or 'none'}); largest |w_out| "
                   f"{med(bad, 'w_out_max'):.3g} against {med(good, 'w_out_max'):.3g}; "
                   f"largest |z| beyond {zmax(bad):.3g} against {zmax(good):.3g}.")
    cov = s["rows"][0]["coverage"]
    out += ["", "The window's coverage (first row, seed 0's input scaling; scaled units): "
            + "; ".join(f"{c} inside [{r['inside'][0]:.2f}, {r['inside'][1]:.2f}], beyond "
                        f"[{r['beyond'][0]:.2f}, {r['beyond'][1]:.2f}]" for c, r in cov.items())
            + "."]
    return "\n".join(out) + "\n"


def draw(s: dict, path) -> None:
    """Left: per seed of the first row, its largest output weight against its force rms beyond
    the window (red: runs away; dashed: the flag's level); right: every unit's largest |z| inside
    the window against its |output weight|."""
    import matplotlib.pyplot as plt

    row, lip = s["rows"][0], s["lip"]["training"]["outside"]
    fig, ax = plt.subplots(1, 2, figsize=(9, 3.6))
    for v in row["seeds"]:
        c = "C3" if v["runaway"] else "C0"
        x, y = v["w_out_max"], v["force_rms"]["training"]["outside"]
        ax[0].loglog(x, y, "o", color=c)
        ax[0].annotate(str(v["seed"]), (x, y), fontsize=7)
        ax[1].semilogy(v["units_z_inside"], np.abs(v["units_w_out"]), ".", color=c, alpha=0.6)
    ax[0].axhline(s["runaway_factor"] * lip, ls="--", color="k", lw=0.8)
    ax[0].set_xlabel("largest |w_out|")
    ax[0].set_ylabel("force rms beyond the window, training [N]")
    ax[0].set_title(f"{row['label']} (red: runs away)", fontsize=7, loc="left")
    ax[1].set_xlabel("unit's largest |z| inside the window")
    ax[1].set_ylabel("|w_out| of the unit")
    ax[1].set_title("every unit of every seed", fontsize=8, loc="left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    from experiments.config import load_config

    p = argparse.ArgumentParser(prog="python -m experiments.studies.emps.runaway")
    p.add_argument("config", nargs="?", default="experiments/configs/emps_pgnn.yaml")
    p.add_argument("--out", default="results/emps_runaway")
    p.add_argument("--rows", default="2,1,5",
                   help="indices of the config's feedforwards to fit (default: lambda = 0.01 "
                        "and lambda = 0 on the paper's cost, lambda = 0.01 with weight decay)")
    p.add_argument("--seeds", type=int, default=None, help="seeds per row (default: the config's)")
    a = p.parse_args(sys.argv[1:] if argv is None else argv)
    config = load_config(a.config)
    pick = [int(i) for i in a.rows.split(",")]
    config = replace(config, feedforwards=tuple(
        config.feedforwards[i] if a.seeds is None else replace(config.feedforwards[i],
                                                               seeds=a.seeds) for i in pick))
    s = compute(config, progress=lambda m: print(m, file=sys.stderr))
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "runaway.json").write_text(json.dumps(s, indent=1))
    (out / "report.md").write_text(report(s))
    draw(s, out / "runaway.png")
    print(report(s))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
