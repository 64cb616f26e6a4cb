"""The identifiability study's figure, beside the study (:mod:`experiments.studies.profiles.study`):
it draws the typed record (:class:`~experiments.studies.profiles.result.SizeRecord`) in the house
style of :mod:`experiments.plots` and computes nothing."""

from __future__ import annotations

from matplotlib.figure import Figure

from clm_sim.plant import THETA_NAMES, THETA_UNITS
from experiments.plots import _ax, _figure, _legend_right, color
from experiments.studies.profiles.result import SizeRecord


def plot_profile(ident: dict[int, SizeRecord], name: str, ax=None):
    """The data cost's profile over parameter ``name`` (above the best data cost, N²) per
    network size, the threshold δ, and the λ = 0 fits at their θ (a fit beyond the grid is
    drawn at its edge as a triangle pointing out; data costs are those of each fit, its data
    term alone). A point that passed the optimizer's own test (a relative decrease of at most
    ftol predicted) is filled; a stop (resolved to the profile's resolution, or neither: an
    upper bound on the profile) is hollow, a resolved one with a dot inside; a
    point continued further (a rise confirmed, or the resolution checked) has a segment to
    where the longer descent took it (a triangle)."""
    ax = _ax(ax)
    for i, (key, rec) in enumerate(ident.items()):
        e = rec.parameters[name]
        pts = sorted(e.points, key=lambda p: p.value)
        best = rec.best_data_cost
        ax.plot([p.value for p in pts], [p.data_cost - best for p in pts], "-", color=color(i),
                label=f"profile, n_l={key}")
        for converged in (True, False):
            sel = [p for p in pts if p.relative_test == converged]
            ax.plot([p.value for p in sel], [p.data_cost - best for p in sel], "o", ms=3,
                    ls="none", mec=color(i), mfc=color(i) if converged else "white")
        resolved = [p for p in pts if p.resolution_test and not p.relative_test]
        ax.plot([p.value for p in resolved], [p.data_cost - best for p in resolved], ".",
                ms=1.5, ls="none", color=color(i))
        # Continued points (a rise confirmed, or a resolved point checked): where they were
        # and where the longer descent took them.
        moves = [(p.value, p.confirmed_from, p.data_cost) for p in pts
                 if p.confirmed_from is not None]
        moves += [(c.value, c.data_cost, c.continued_cost) for c in rec.checks if c.name == name]
        for v, before, after in moves:
            ax.plot([v, v], [before - best, after - best], "-", lw=1, color=color(i))
            ax.plot([v], [after - best], "v", ms=5, ls="none", mec=color(i), mfc="none")
        ax.axhline(rec.delta, color=color(i), ls=":", lw=1, label=f"δ, n_l={key}")
        lo, hi = e.bound
        for f in rec.fits:
            lam0 = not f.lam
            v = f.theta[name]
            marker = "x" if lam0 else "+"
            if v < lo or v > hi:
                v, marker = (lo, "<") if v < lo else (hi, ">")
            ax.plot([v], [max(f.data_cost - best, 0.0)], marker, ms=6, ls="none",
                    mec=color(i), mfc="none", alpha=0.7)
    ax.plot([], [], "o", ms=3, color="0.3", ls="none", label="converged (optimizer's test)")
    ax.plot([], [], "o", ms=3, mec="0.3", mfc="white", ls="none",
            label="a stop: resolved (dot) or neither (upper bounds)")
    ax.plot([], [], "v", ms=5, mec="0.3", mfc="none", ls="none",
            label="continued (check, or a rise confirmed)")
    ax.plot([], [], "x", color="0.3", ls="none", label="λ = 0 fits (colour: n_l)")
    ax.set_xlabel(f"{name} [{THETA_UNITS[name]}]")
    ax.set_ylabel("data cost − best [N²]")
    return ax


def identifiability_figure(ident: dict[int, SizeRecord]) -> Figure:
    """One panel per physical parameter: :func:`plot_profile`; ``ident``: per network size n_l,
    the study's :class:`~experiments.studies.profiles.result.SizeRecord`."""
    fig = _figure(11.0, 7.0)
    axes = fig.subplots(2, 2).ravel()
    for ax, name in zip(axes, THETA_NAMES):
        plot_profile(ident, name, ax)
        ax.set_yscale("symlog", linthresh=max(r.delta for r in ident.values()))
    _legend_right(axes[1])
    return fig
