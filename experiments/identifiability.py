"""What the data determine: the profile of the PGNN data cost over each physical parameter.

For one network size, parameter ``k`` is held at each value of a grid around theta_LIP and
everything else (the other three physical parameters, the network) is re-fitted to the data cost
alone (lambda = 0, no weight decay; :meth:`controllers.pgnn.PGNNFeedforward.fit_pinned`, started
from the hidden layers of the lowest-cost fit of the table at that size). The profile
``V_k(value)`` is the lowest mean squared error (N**2) that the data allow with ``theta_k`` there.

The range of ``theta_k`` that the data determine is the set of grid values where the profile stays
within ``delta`` of the best data cost ``V*`` (the lowest of every profile point and every fit of
the table at that size). ``delta`` is the larger of

* the noise threshold: a likelihood-ratio test of one parameter at 95 % under white Gaussian
  errors, ``chi2_1(0.95) * V* / N_eff``, with ``N_eff`` the independent samples in the fitting
  data: at most the samples kept, at most ``2 B T`` for data low-passed to ``B`` Hz over ``T`` s;
* the optimizer's own spread: the sample standard deviation of the data cost over the seeds of
  the row with the lowest mean data cost at that size (below that, two fits cannot be told apart
  by their cost).

A range that reaches the end of the grid (``theta_LIP +- span * scale_k``, ``scale_k`` the change
of ``theta_k`` that alone moves the force by its rms on the training data) is open on that side.
The profile assumes that ``max_iter`` Levenberg-Marquardt iterations from one start reach the
profile's minimum: each point is an upper bound, so a range can only be too narrow.
"""

from __future__ import annotations

import numpy as np
import scipy.stats

from clm_sim.plant import THETA_NAMES

GRID = (-1.0, -0.3, -0.1, 0.0, 0.1, 0.3, 1.0)  # in units of span * scale_k around theta_LIP


CONFIDENCE = 0.95


def n_effective(n_samples: int, duration_s: float, bandwidth_hz: float | None) -> float:
    """Independent samples in fitting data of ``n_samples`` spanning ``duration_s`` s after a
    low-pass to ``bandwidth_hz`` (None: unfiltered): at most ``2 B T`` (Nyquist)."""
    n_eff = float(n_samples)
    if bandwidth_hz is not None:
        n_eff = min(n_eff, 2.0 * bandwidth_hz * duration_s)
    return n_eff


def grid(theta_lip: dict, phi: np.ndarray, target: np.ndarray, span: float) -> dict:
    """Per parameter: the values held (SI units) and the scale (change that alone moves the
    force by its rms)."""
    rms_f = float(np.sqrt(np.mean(target ** 2)))
    out = {}
    for k, name in enumerate(THETA_NAMES):
        scale = rms_f / max(float(np.sqrt(np.mean(phi[:, k] ** 2))), 1e-300)
        out[name] = {"scale": scale,
                     "values": [theta_lip[name] + g * span * scale for g in GRID]}
    return out


def valley_range(values, costs, v_best: float, delta: float) -> dict:
    """The contiguous block of grid ``values`` around the profile's lowest point where
    ``costs <= v_best + delta``: ``{"range": [low, high], "open": [low_open, high_open],
    "inside_grid": [first, last grid value inside]}``; a closed end is where the profile,
    interpolated linearly between grid points, crosses ``v_best + delta``; open: the block
    reaches that end of the grid (the range's end is then the search bound)."""
    values, costs = np.asarray(values, float), np.asarray(costs, float)
    order = np.argsort(values)
    values, costs = values[order], costs[order]
    inside = costs <= v_best + delta
    i = int(np.argmin(costs))
    if not inside[i]:  # the profile never comes within delta of the best fit
        return {"range": None, "open": [False, False]}
    lo = hi = i
    while lo > 0 and inside[lo - 1]:
        lo -= 1
    while hi < len(values) - 1 and inside[hi + 1]:
        hi += 1
    level = v_best + delta

    def edge(inner, outer):  # where the profile crosses the level between two grid points
        c0, c1 = costs[inner] - level, costs[outer] - level
        return float(values[inner] + (values[outer] - values[inner]) * c0 / (c0 - c1))

    low = float(values[0]) if lo == 0 else edge(lo, lo - 1)
    high = float(values[-1]) if hi == len(values) - 1 else edge(hi, hi + 1)
    return {"range": [low, high], "open": [lo == 0, hi == len(values) - 1],
            "inside_grid": [float(values[lo]), float(values[hi])]}


def in_range(value: float, entry: dict) -> bool:
    """Whether ``value`` lies in ``entry["range"]`` (an open side extends to infinity)."""
    if entry["range"] is None:
        return False
    lo, hi = entry["range"]
    return ((entry["open"][0] or value >= lo) and (entry["open"][1] or value <= hi))


def summarize(profile: dict[str, list[dict]], fits: list[dict], v_spread: float,
              n_eff: float) -> dict:
    """The identifiability record of one network size from the profile points
    ``{name: [{"value", "data_cost", "mae": {ref: m}}]}`` and the table's fits at that size
    (``[{"label", "data_cost", "theta"}]``)."""
    v_best = min([p["data_cost"] for pts in profile.values() for p in pts]
                 + [f["data_cost"] for f in fits])
    delta_noise = float(scipy.stats.chi2.ppf(CONFIDENCE, 1) * v_best / n_eff)
    delta = max(delta_noise, v_spread)
    out = {"best_data_cost": v_best, "delta": delta, "delta_noise": delta_noise,
           "n_eff": n_eff, "delta_spread_over_seeds": v_spread,
           "delta_from": "noise" if delta_noise >= v_spread else "spread over seeds",
           "fits": fits, "parameters": {}}
    valley = {}
    for name, pts in profile.items():
        entry = valley_range([p["value"] for p in pts], [p["data_cost"] for p in pts],
                             v_best, delta)
        entry["profile"] = [{"value": p["value"], "data_cost": p["data_cost"],
                             "stop": p.get("stop"), "mae": p.get("mae")} for p in pts]
        entry["bound"] = [min(p["value"] for p in pts), max(p["value"] for p in pts)]
        ends = []
        if entry["range"] is not None:  # the pinned fits at the ends of the block inside
            ends = [p for p in pts if p["value"] in entry["inside_grid"]]
        entry["mae_at_ends"] = [{"value": p["value"], "mae": p.get("mae")} for p in ends]
        for p in pts:
            if p["data_cost"] <= v_best + delta and p.get("mae"):
                for ref, m in p["mae"].items():
                    valley.setdefault(ref, []).append(m)
        out["parameters"][name] = entry
    out["valley_mae"] = {ref: [float(min(v)), float(max(v)), len(v)]
                         for ref, v in valley.items()}
    return out


def rows_against(ident: dict, rows: list[dict]) -> None:
    """Add to every PGNN row ``theta_in_identified_range``: per parameter, how many of its seeds'
    theta_phy lie in the range the data determine at its network size."""
    for row in rows:
        key = _size_key(row.get("hidden"))
        if row["kind"] != "pgnn" or key not in ident or not row.get("theta_phy_per_seed"):
            continue
        params = ident[key]["parameters"]
        row["theta_in_identified_range"] = {
            name: sum(in_range(t[name], params[name]) for t in row["theta_phy_per_seed"])
            for name in THETA_NAMES}


def _size_key(hidden) -> str:
    if hidden is None:
        return ""
    widths = (hidden,) if isinstance(hidden, int) else tuple(hidden)
    return "x".join(map(str, widths))


def lip_intervals(phi: np.ndarray, target: np.ndarray) -> dict:
    """The LIP (least squares of ``target`` on ``phi``'s four columns, named) on the fitting
    samples, with white-noise and Newey-West (autocorrelation-robust) standard errors and the
    residual's lag-1 autocorrelation (:func:`experiments.hac.newey_west`)."""
    from experiments.hac import newey_west

    fit = newey_west(phi, target)
    return {"theta": dict(zip(THETA_NAMES, map(float, fit["theta"]))),
            "std_white": dict(zip(THETA_NAMES, map(float, fit["std_white"]))),
            "std_newey_west": dict(zip(THETA_NAMES, map(float, fit["std_newey_west"]))),
            "lag1_autocorr": fit["lag1_autocorr"], "lags": fit["lags"],
            "n_samples": int(len(target))}


def _lip_line(rec: dict) -> str:
    from experiments.table import THETA_UNITS

    li = rec["lip_intervals"]
    return (f"LIP on the same {li['n_samples']} fitting samples, 95 % intervals (white noise / "
            f"Newey-West with {li['lags']} lags; residual lag-1 autocorrelation "
            f"{li['lag1_autocorr']:.2f}): " + "; ".join(
                f"{n} {li['theta'][n]:.4g} ± {1.96 * li['std_white'][n]:.2g} / ± "
                f"{1.96 * li['std_newey_west'][n]:.2g} {THETA_UNITS[n]}" for n in THETA_NAMES)
            + ".")


def to_markdown(ident: dict, rows: list[dict]) -> str:
    """The ranges per network size, how each row's theta lies against them, and the MAE over
    the valley."""
    from experiments.table import THETA_UNITS

    lines = ["", "**What the data determine** (profile of the data cost over each physical "
             "parameter, everything else re-fitted; range: where the profile stays within δ of "
             "the best data cost; ↔ open: reaches the search bound):", ""]
    for key, rec in ident.items():
        lines += [f"n_l = {key}: best data cost {rec['best_data_cost']:.5f} N², δ = "
                  f"{rec['delta']:.2g} N² (from the {rec['delta_from']}; noise threshold "
                  f"{rec['delta_noise']:.2g} N² with N_eff = {rec['n_eff']:.0f}, spread over "
                  f"seeds {rec['delta_spread_over_seeds']:.2g} N²)", "",
                  "| parameter | range | search bound | MAE of the pinned fits at the ends "
                  "of the grid points inside |",
                  "|---|---|---|---|"]
        for name, e in rec["parameters"].items():
            unit = THETA_UNITS[name]
            if e["range"] is None:
                rng = "none within δ"
            else:
                lo, hi = e["range"]
                rng = (("(open) " if e["open"][0] else "") + f"[{lo:.4g}, {hi:.4g}]"
                       + (" (open)" if e["open"][1] else "") + f" {unit}")
            ends = "; ".join(
                f"{p['value']:.4g}: " + ", ".join(f"{ref} {m * 1e6:.3f} µm"
                                                  for ref, m in (p["mae"] or {}).items())
                for p in e["mae_at_ends"])
            lines.append(f"| {name} | {rng} | [{e['bound'][0]:.4g}, {e['bound'][1]:.4g}] | "
                         f"{ends or '–'} |")
        stops = [p.get("stop") for e in rec["parameters"].values()
                 for p in e.get("profile", [])]
        if stops and None not in stops:
            lines += ["", f"Profile points: {stops.count('converged')} of {len(stops)} "
                      f"converged ({', '.join(f'{stops.count(x)} {x}' for x in sorted(set(stops)) if x != 'converged') or 'all'}); "
                      "a point that did not converge is an upper bound on the profile there."]
        if "lip_intervals" in rec:
            lines += ["", _lip_line(rec)]
        lines += ["", "MAE over the valley (every profile fit within δ): " + "; ".join(
            f"{ref} {lo * 1e6:.3f} … {hi * 1e6:.3f} µm ({n} fits)"
            for ref, (lo, hi, n) in rec["valley_mae"].items()) + ".", ""]
        mine = [r for r in rows if "theta_in_identified_range" in r
                and _size_key(r["hidden"]) == key]
        if mine:
            lines += ["| row | " + " | ".join(f"{n} in range" for n in THETA_NAMES) + " |",
                      "|---|" + "---|" * len(THETA_NAMES)]
            for r in mine:
                lines.append(f"| {r['label']} | " + " | ".join(
                    f"{r['theta_in_identified_range'][n]}/{r['n_seeds']}"
                    for n in THETA_NAMES) + " |")
            lines.append("")
    return "\n".join(lines)
