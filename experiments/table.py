"""The results table shared by every experiment: rows in one JSON schema, also as Markdown and CSV.

``table.json`` is ``{"rows": [row, ...]}`` with each row
``{"kind", "training", "lambda", "hidden", "n_seeds", "mae": {ref: {"mean", "std"}}, "theta_phy"}``
(MAE in metres); extra keys (label, rms, max, swept keys) are allowed after those.
"""

from __future__ import annotations

import csv
import io
import json

import numpy as np

from clm_sim.plant import THETA_NAMES


def tracking_metrics(e: np.ndarray) -> dict[str, float]:
    """MAE, RMS and max of a tracking error (m)."""
    e = np.asarray(e, dtype=float)
    return {"mae": float(np.mean(np.abs(e))), "rms": float(np.sqrt(np.mean(e**2))),
            "max": float(np.max(np.abs(e)))}


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


def _um(stat: dict) -> str:
    s = f"{stat['mean'] * 1e6:.3f}"
    return s + (f" ± {stat['std'] * 1e6:.3f}" if stat["std"] else "")


def to_markdown(rows: list[dict]) -> str:
    """A Markdown table: MAE (um, mean ± std over seeds) per reference and theta_phy."""
    refs = list(rows[0]["mae"])
    head = (["feedforward", "seeds"] + [f"MAE {r} [µm]" for r in refs]
            + ["m [kg]", "fv [N·s/m]", "fc [N]", "fk [N/m]"])
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in rows:
        th = row["theta_phy"]
        theta = [f"{th[k]:.4g}" for k in THETA_NAMES] if th else ["–"] * 4
        cells = [row["label"], str(row["n_seeds"])] + [_um(row["mae"][r]) for r in refs] + theta
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def to_csv(rows: list[dict]) -> str:
    refs = list(rows[0]["mae"])
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(["label", "kind", "training", "lambda", "hidden", "n_seeds"]
               + [f"mae_{r}_{s}_m" for r in refs for s in ("mean", "std")]
               + [f"theta_{k}" for k in THETA_NAMES])
    for row in rows:
        th = row["theta_phy"] or {}
        w.writerow([row["label"], row["kind"], row["training"] or "", "" if row["lambda"] is None
                    else row["lambda"], row["hidden"] or "", row["n_seeds"]]
                   + [f"{row['mae'][r][s]:.6e}" for r in refs for s in ("mean", "std")]
                   + [f"{th[k]:.6g}" if th else "" for k in THETA_NAMES])
    return out.getvalue()
