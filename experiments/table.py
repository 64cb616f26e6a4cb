"""The results table shared by every experiment: rows in one JSON schema, also as Markdown and CSV.

``table.json`` is ``{"rows": [row, ...]}`` with each row
``{"kind", "training", "lambda", "hidden", "n_seeds", "mae": {ref: {"mean", "std"}}, "theta_phy"}``
(MAE in metres); extra keys (label, rms, max, swept keys) are allowed after those. Sweeps
also summarize their rows over the swept seeds (:func:`over_seeds`).
"""

from __future__ import annotations

import csv
import io
import json
import re

import numpy as np

from clm_sim.plant import THETA_NAMES

THETA_UNITS = {"mass": "kg", "viscous": "N·s/m", "coulomb": "N", "stiffness": "N/m"}


def make_row(spec, metrics_per_seed: list[dict[str, dict[str, float]]],
             thetas: list[dict[str, float]] | None) -> dict:
    """One table row from per-seed metrics ``[{ref: {"mae", "rms", "max"}}]`` and thetas."""
    refs = list(metrics_per_seed[0])

    def stat(ref, key):
        vals = np.array([m[ref][key] for m in metrics_per_seed])
        return {"mean": float(vals.mean()), "std": float(vals.std(ddof=1) if len(vals) > 1 else 0.0)}

    theta = None
    if thetas:
        theta = {k: float(np.mean([t[k] for t in thetas])) for k in THETA_NAMES}
    return {
        "kind": spec.kind, "training": spec.training, "lambda": spec.lam, "hidden": spec.hidden,
        "n_seeds": len(metrics_per_seed),
        "mae": {ref: stat(ref, "mae") for ref in refs},
        "theta_phy": theta,
        "label": spec.label(),
        "rms": {ref: stat(ref, "rms") for ref in refs},
        "max": {ref: stat(ref, "max") for ref in refs},
        "theta_phy_per_seed": thetas or None,
    }


def to_json(rows: list[dict]) -> str:
    return json.dumps({"rows": rows}, indent=1)


_SHORT = {"mass": "m", "viscous": "fv", "coulomb": "fc", "stiffness": "fk"}


def _fmt(value) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def _um(stat: dict) -> str:
    s = f"{stat['mean'] * 1e6:.3f}"
    return s + (f" ± {stat['std'] * 1e6:.3f}" if stat["std"] else "")


def to_markdown(rows: list[dict], swept: list[str] = (), failures: list[dict] = ()) -> str:
    """A Markdown table, one line per row: the ``swept`` keys' values (sweeps), the
    feedforward, its seeds, MAE (µm, mean ± std over seeds) per reference and theta_phy; then
    the ``failures`` of a sweep (``{key: value, ..., "error"}``) as a list."""
    refs = list(rows[0]["mae"]) if rows else []
    head = (list(swept) + ["feedforward", "seeds"] + [f"MAE {r} [µm]" for r in refs]
            + [f"{_SHORT[k]} [{THETA_UNITS[k]}]" for k in THETA_NAMES])
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in rows:
        th = row["theta_phy"]
        theta = [f"{th[k]:.4g}" for k in THETA_NAMES] if th else ["–"] * 4
        cells = ([_fmt(row[k]) for k in swept] + [row["label"], str(row["n_seeds"])]
                 + [_um(row["mae"][r]) for r in refs] + theta)
        lines.append("| " + " | ".join(cells) + " |")
    text = "\n".join(lines) + "\n"
    if failures:
        text += f"\n{len(failures)} failed task(s):\n\n" + "".join(
            "- " + ", ".join(f"{k}={_fmt(f[k])}" for k in swept) + f": {f['error']}\n"
            for f in failures)
    return text


def to_csv(rows: list[dict], swept: list[str] = ()) -> str:
    """CSV, one line per row: the swept keys' values, the row's settings, MAE (m) per
    reference, theta_phy, and for sweeps the task key."""
    refs = list(rows[0]["mae"]) if rows else []
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    task = ["task"] if swept else []
    w.writerow(list(swept) + ["label", "kind", "training", "lambda", "hidden", "n_seeds"]
               + [f"mae_{r}_{s}_m" for r in refs for s in ("mean", "std")]
               + [f"theta_{k}" for k in THETA_NAMES] + task)
    for row in rows:
        th = row["theta_phy"] or {}
        w.writerow([row[k] for k in swept]
                   + [row["label"], row["kind"], row["training"] or "",
                      "" if row["lambda"] is None else row["lambda"], row["hidden"] or "",
                      row["n_seeds"]]
                   + [f"{row['mae'][r][s]:.6e}" for r in refs for s in ("mean", "std")]
                   + [f"{th[k]:.6g}" if th else "" for k in THETA_NAMES]
                   + [row[k] for k in task])
    return out.getvalue()


# ----------------------------------------------------------------------------- over seeds

def seed_stat(stats: list[dict]) -> dict:
    """Mean and spread of one quantity over seeds, from its per-seed ``{"mean", "std"}``: the
    sample std of the means, or with one seed that seed's own std (over training seeds)."""
    means = np.array([s["mean"] for s in stats])
    spread = float(means.std(ddof=1)) if len(means) > 1 else float(stats[0]["std"])
    return {"mean": float(means.mean()), "std": spread, "n": len(means)}


def over_seeds(rows: list[dict], swept: list[str]) -> list[dict]:
    """Rows of a sweep that differ only in the swept ``seed`` merged into one row each, in the
    order they first appear: MAE mean ± sample std over the seeds, theta_phy averaged,
    ``n_seeds`` the number of seeds merged. Rows are matched by feedforward position
    (``row``) and every other swept key."""
    others = [k for k in swept if k != "seed"]
    groups: dict[tuple, list[dict]] = {}
    for row in rows:
        groups.setdefault((row["row"], *(row[k] for k in others)), []).append(row)
    out = []
    for members in groups.values():
        first = members[0]
        thetas = [m["theta_phy"] for m in members if m["theta_phy"]]
        out.append({
            "kind": first["kind"], "training": first["training"], "lambda": first["lambda"],
            "hidden": first["hidden"], "n_seeds": len(members),
            "mae": {ref: {k: v for k, v in seed_stat([m["mae"][ref] for m in members]).items()
                          if k != "n"} for ref in first["mae"]},
            "theta_phy": {k: float(np.mean([t[k] for t in thetas])) for k in THETA_NAMES}
            if thetas else None,
            "label": first["label"], **{k: first[k] for k in others}, "row": first["row"]})
    return out


def _series_labels(rows: list[dict]) -> dict[int, str]:
    """A label per feedforward position that does not change along the sweep."""
    by_pos: dict[int, set] = {}
    for row in rows:
        by_pos.setdefault(row["row"], set()).add(row["label"])
    labels = {}
    for pos, names in by_pos.items():
        if len(names) == 1:
            labels[pos] = next(iter(names))
        else:
            row = next(r for r in rows if r["row"] == pos)
            labels[pos] = {"none": "feedback only", "lip": "LIP"}.get(
                row["kind"], f"PGNN {row['training']}")
    return labels


def _applies(key: str, position: int) -> bool:
    """Whether swept ``key`` can change the row at feedforward ``position`` (a key of another
    feedforward, ``feedforwards[j]...``, cannot)."""
    m = re.match(r"feedforwards\[(\d+)\]", key)
    return m is None or int(m.group(1)) == position


def _key_value(key: str, value) -> str:
    return f"{key.split('.')[-1]}={_fmt(value)}"


def series(rows: list[dict], swept: list[str], x: str, describe=_key_value) -> dict:
    """``{(label, ref): {x_value: (mean, spread, n)}}``: MAE (m) per series and x, with the
    spread over the swept seeds (:func:`seed_stat`). Other swept keys split the series (named
    ``label, describe(key, value), ...``). A row
    that ``x`` cannot change (the LIP when a PGNN's lambda is swept) is one flat series: the
    same statistics at every x; copies of it from grid points that differ only in another
    feedforward's keys count once."""
    labels = _series_labels(rows)
    xs = list(dict.fromkeys(row[x] for row in rows))
    groups: dict = {}
    seen = set()
    for row in rows:
        pos = row["row"]
        applies = [k for k in swept if _applies(k, pos)]
        ident = (pos, tuple(row[k] for k in applies))
        if ident in seen:
            continue
        seen.add(ident)
        name = labels[pos] + "".join(f", {describe(k, row[k])}"
                                     for k in applies if k not in (x, "seed"))
        for ref, stat in row["mae"].items():
            by_x = groups.setdefault((name, ref), {})
            for xv in ([row[x]] if x in applies else xs):
                by_x.setdefault(xv, []).append(stat)
    return {key: {xv: tuple(seed_stat(stats).values()) for xv, stats in by_x.items()}
            for key, by_x in groups.items()}
