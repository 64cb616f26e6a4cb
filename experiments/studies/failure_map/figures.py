"""The failure map's figures, beside the study (:mod:`experiments.studies.failure_map.study`): they
draw its typed result (:class:`~experiments.studies.failure_map.result.FailureMapResult`) in the
house style of :mod:`experiments.plots` and compute nothing."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter

from clm_sim.plant import THETA_NAMES
from experiments.plots import PALETTE, _ax, _figure, _legend_right, color
from experiments.studies.failure_map.result import FailureMapResult

# Palette indices for the cases (black first: the plant without parasitic force) and for n_l,
# chosen so that no two neighbours are the two blues or the two oranges.
_CASE_COLORS = (0, 1, 3, 6, 5, 2, 4, 8, 9, 7)
_SIZE_COLORS = (5, 4, 3, 6, 1)


def _ratio_axis(ax, which: str) -> None:
    """A log axis of ratios labelled in plain numbers (0.5, 0.7, 1, 1.5, ...; never 10^-1), with
    finer steps when the data span less than a decade. Call after the data are drawn."""
    from matplotlib.ticker import FixedLocator, NullFormatter

    ax.autoscale_view()
    lo, hi = ax.get_xlim() if which == "x" else ax.get_ylim()
    span = np.log10(hi / lo) if lo > 0 and hi > lo else 1.0
    steps = ((1, 2, 5) if span > 1.5 else (1, 1.5, 2, 3, 5, 7) if span > 0.6 else
             (1, 1.2, 1.5, 2, 2.5, 3, 4, 5, 6, 7, 8))
    axis = ax.xaxis if which == "x" else ax.yaxis
    axis.set_major_locator(FixedLocator([m * 10.0**e for e in range(-3, 4) for m in steps]))
    axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    axis.set_minor_formatter(NullFormatter())


def plot_failure_ratios(result: FailureMapResult, direction: str, ax=None):
    """MAE(λ = 0)/MAE(λ) on the reference that leaves the training range in ``direction``, per
    case (rows) and n_l (colours), with the paired interval
    (``experiments.studies.failure_map.study``); log axis, 1 marked (right of it: λ = 0 loses)."""
    ax = _ax(ax)
    st = result.settings
    cases, hidden = list(st.cases), st.hidden
    cells = {(c.case, c.hidden): c for c in result.cells if c.direction == direction}
    offsets = np.linspace(-0.25, 0.25, len(hidden)) if len(hidden) > 1 else [0.0]
    for j, (h, dy) in enumerate(zip(hidden, offsets)):
        pts = [(i + dy, cells[(case, h)].ratio) for i, case in enumerate(cases)
               if (case, h) in cells]
        if not pts:
            continue
        r = np.array([[p.ratio, p.low, p.high] for _, p in pts])
        ax.errorbar(r[:, 0], [y for y, _ in pts], xerr=[r[:, 0] - r[:, 1], r[:, 2] - r[:, 0]],
                    fmt="o", color=color(_SIZE_COLORS[j % 5]), capsize=3, label=f"n_l = {h}")
    ax.axvline(1.0, color="k", lw=0.8)
    ax.set_xscale("log")
    _ratio_axis(ax, "x")
    ax.set_yticks(range(len(cases)), cases)
    ax.set_ylim(len(cases) - 0.5, -0.5)
    ref = st.outside[direction]
    ax.set_xlabel(f"MAE(λ = 0) / MAE(λ = {st.lam:g}) on {ref} [–]")
    ax.set_title(f"leaves the training range in {direction} ({ref})", loc="left", fontsize=9)
    ax.grid(alpha=0.3, which="both", axis="x")
    return ax


def plot_failure_mechanism(result: FailureMapResult, ax=None):
    """Per extrapolation cell of a failure map, the MAE ratio against the ratio of the model's
    rms force error beyond the training range (λ = 0 over λ, both [–]); colour: case, marker:
    direction; bars: the MAE ratio's interval."""
    from matplotlib.lines import Line2D

    ax = _ax(ax)
    st = result.settings
    cases, directions = list(st.cases), list(st.outside)
    markers = "os^vD"
    for c in result.outside:
        e0 = c.network.unregularized.error_beyond_rms_n
        e1 = c.network.regularized.error_beyond_rms_n
        if not (e0 and e1):
            continue
        r = c.ratio
        ax.errorbar(e0 / e1, r.ratio, yerr=[[r.ratio - r.low], [r.high - r.ratio]],
                    fmt=markers[directions.index(c.direction) % len(markers)],
                    color=color(_CASE_COLORS[cases.index(c.case) % 10]), capsize=2,
                    alpha=0.85)
    ax.axhline(1.0, color="k", lw=0.8)
    ax.axvline(1.0, color="k", lw=0.8, ls=":")
    ax.set_xscale("log")
    ax.set_yscale("log")
    _ratio_axis(ax, "x")
    _ratio_axis(ax, "y")
    ax.set_xlabel(f"force error beyond the training range, rms, λ = 0 / λ = {st.lam:g} [–]")
    ax.set_ylabel(f"MAE(λ = 0) / MAE(λ = {st.lam:g}) [–]")
    ax.grid(alpha=0.3, which="both")
    handles = [Line2D([], [], color=color(_CASE_COLORS[i % 10]), marker="o", ls="", label=case)
               for i, case in enumerate(cases)]
    handles += [Line2D([], [], color=PALETTE[7], marker=markers[i % len(markers)], ls="",
                       label=f"{d} ({st.outside[d]})") for i, d in enumerate(directions)]
    _legend_right(ax, handles=handles)
    return ax


def plot_theta_drift(result: FailureMapResult, hidden: int, ax=None):
    """The drift of θ_phy under λ = 0 per case of a failure map, as the force it moves at the
    edge of the training range (|θ_phy − θ_LIP| times the largest |a|, |v|, 1, |y| of the
    training reference, N, mean over seeds), one bar per parameter."""
    ax = _ax(ax)
    feature = {"mass": "a", "viscous": "v", "coulomb": "sign v", "stiffness": "y"}
    cases = list(result.settings.cases)
    width = 0.8 / len(THETA_NAMES)
    drift = {case: result.drift.get((case, hidden)) for case in cases}  # None: no cell computed
    for j, k in enumerate(THETA_NAMES):
        vals = [d.theta.unregularized[k].edge_force_n if d else np.nan for d in drift.values()]
        ax.bar(np.arange(len(cases)) + (j - (len(THETA_NAMES) - 1) / 2) * width, vals, width,
               color=color((5, 1, 3, 6)[j % 4]),
               label=f"{k} × max |{feature[k]}|")
    ax.set_xticks(range(len(cases)), cases, rotation=20, fontsize=8)
    ax.set_ylabel("|θ_phy − θ_LIP| × max |feature| [N]")
    ax.set_title(f"drift of θ_phy with λ = 0, n_l = {hidden}", loc="left", fontsize=9)
    ax.grid(alpha=0.3, axis="y")
    return ax


def failure_map_figures(result: FailureMapResult) -> dict[str, Figure]:
    """The failure map's figures by file stem: ``ratio`` (one panel per direction),
    ``mechanism`` and ``drift`` (one panel per n_l)."""
    directions = list(result.settings.outside)
    hidden = result.settings.hidden
    ratio = _figure(4.6 * len(directions) + 1.4, 4.2)
    axes = np.atleast_1d(ratio.subplots(1, len(directions), sharex=True))
    for ax, d in zip(axes, directions):
        plot_failure_ratios(result, d, ax)
    _legend_right(axes[-1])
    mechanism = _figure(8.5, 4.6)
    plot_failure_mechanism(result, mechanism.subplots())
    drift = _figure(4.6 * len(hidden) + 1.8, 4.2)
    axes = np.atleast_1d(drift.subplots(1, len(hidden), sharey=True))
    for ax, h in zip(axes, hidden):
        plot_theta_drift(result, h, ax)
    _legend_right(axes[-1])
    return {"ratio": ratio, "mechanism": mechanism, "drift": drift}
