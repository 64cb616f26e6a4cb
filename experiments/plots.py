"""The house style of clm-sim's figures and the panels of a run (reference, tracking error,
feedforward). The figures of a subject sit beside it (:mod:`experiments.sweeps.figures`,
:mod:`experiments.diagnosis.figures`, each study's ``figures``) and draw with the helpers here.
Figures take
results and never run a model (no ``predict``): whoever computed a result hands it over.

Two kinds of functions. ``plot_*(..., ax=None) -> Axes`` draw one panel on ``ax`` (default: the
current pyplot axes, for notebooks). ``*_figure(...) -> Figure`` compose a whole figure from
panels without pyplot, so writing files needs no backend; :func:`save` writes one atomically.
No backend is chosen here (the CLI picks Agg). One palette (Okabe–Ito, colour-blind safe), units
on every axis, legends outside the data.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from clm_sim.outdir import atomic_write


# Okabe & Ito's colour-blind-safe set (yellow left out: unreadable on white), then grey, and
# Tol's wine and olive (apart from every colour before them).
PALETTE = ("#000000", "#E69F00", "#56B4E9", "#009E73", "#D55E00", "#0072B2", "#CC79A7",
           "#999999", "#882255", "#999933")
UM, MM = 1e6, 1e3  # m -> µm, m -> mm

def color(i: int) -> str:
    """The ``i``-th colour of the palette (cycling)."""
    return PALETTE[i % len(PALETTE)]


def _ax(ax):
    if ax is None:
        import matplotlib.pyplot as plt
        ax = plt.gca()
    return ax


def _figure(width: float, height: float) -> Figure:
    return Figure(figsize=(width, height), layout="constrained")


def _legend_right(ax, **kwargs) -> None:
    """A legend beside the panel, never on the data."""
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0, fontsize=8,
              frameon=False, **kwargs)


def save(fig: Figure, path, dpi: int = 110) -> Path:
    """Write ``fig`` to ``path`` (format from the suffix) atomically. Every text is drawn as
    written: names from files and configs are never TeX (``$x^$`` in a row's name would stop
    the drawing) and a control character is shown as ``?`` (no font has a glyph for it)."""
    from matplotlib.text import Text

    for text in fig.findobj(Text):
        text.set_parse_math(False)
        shown = text.get_text()
        if not shown.replace("\n", "").isprintable():
            text.set_text("".join(c if c.isprintable() or c == "\n" else "?" for c in shown))
    return atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=dpi,
                                                      format=Path(path).suffix.lstrip(".")))


# ----------------------------------------------------------------------------- runs

ENVELOPE_BUCKETS = 2000  # time buckets of a long signal's line: two points per pixel or more


def envelope(t: np.ndarray, y: np.ndarray, buckets: int = ENVELOPE_BUCKETS):
    """``(t, y)`` reduced to each time bucket's smallest and largest sample, in time order,
    with the first and the last: at the width of a figure the same line (every extreme is
    kept), drawn from 4,000 points instead of 176,000 (a replay on r1) or more."""
    n = len(y)
    if n <= 4 * buckets:
        return t, y
    width = n // buckets
    blocks = y[:width * buckets].reshape(buckets, width)
    base = np.arange(buckets) * width
    keep = np.concatenate([[0, n - 1], base + blocks.argmin(axis=1),
                           base + blocks.argmax(axis=1), np.arange(width * buckets, n)])
    keep = np.unique(keep)
    return t[keep], y[keep]


def plot_reference(run, ax=None):
    """The reference position r (mm) against time (s)."""
    ax = _ax(ax)
    ax.plot(*envelope(run.t, run.r * MM), color="k", lw=1)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("r [mm]")
    ax.grid(alpha=0.3)
    return ax


def plot_tracking_error(run, ax=None, *, label: str | None = None, color: str = PALETTE[0],
                        note: str = ""):
    """The tracking error e = r − y (µm) against time (s); the title names ``label``, the MAE of
    this run and ``note`` (e.g. which seed this is and the table's mean over seeds)."""
    ax = _ax(ax)
    ax.plot(*envelope(run.t, run.e * UM), color=color, lw=0.7)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("e [µm]")
    ax.grid(alpha=0.3)
    if label:
        ax.set_title(f"{label}: MAE {run.mae * UM:.3f} µm{note}", loc="left", fontsize=9,
                     color=color)
    return ax


def plot_feedforward(run, ax=None, *, base=None, label: str | None = None,
                     color: str = PALETTE[0]):
    """The feedforward force u_ff (N) against time (s), or its difference from ``base`` (a run
    on the same reference) when given."""
    ax = _ax(ax)
    force = run.u_ff if base is None else run.u_ff - base.u_ff
    ax.plot(*envelope(run.t, force), color=color, lw=0.7)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("u_ff [N]" if base is None else "Δu_ff [N]")
    ax.grid(alpha=0.3)
    if label:
        ax.set_title(label, loc="left", fontsize=9, color=color)
    return ax


def _panels(n: int, heights: list[float], width: float = 10.0):
    """A figure of ``n`` panels stacked on one time axis, ``heights`` relative."""
    fig = _figure(width, 0.45 + 1.25 * sum(heights))
    axes = fig.subplots(n, 1, sharex=True, gridspec_kw={"height_ratios": heights})
    return fig, np.atleast_1d(axes)


def tracking_figure(replays: dict, ref: str, colors: dict | None = None,
                    rows: list[dict] | None = None) -> Figure:
    """``replays[label][ref]`` are Runs on reference ``ref`` in table order. Panels: the
    reference; feedback only (its own scale); then one panel per feedforward on one shared
    scale, so that LIP and PGNN errors compare at a glance. Feedback only is the run whose
    feedforward is zero throughout. ``colors``: per label (default: the palette in order).
    ``rows``: the table rows; a row over several seeds then says that its panel shows seed 0
    and gives the table's mean ± std beside it."""
    stats = {row.label: row for row in rows or ()}
    runs = {label: r[ref] for label, r in replays.items()}
    colors = colors or {label: color(i) for i, label in enumerate(runs)}
    fb = [label for label, run in runs.items() if not np.any(run.u_ff)]
    ff = [label for label in runs if label not in fb]
    fig, axes = _panels(1 + len(fb) + len(ff), [0.8] + [1.0] * (len(fb) + len(ff)))
    for ax in axes[2 + len(fb):]:
        ax.sharey(axes[1 + len(fb)])  # shared before plotting: the scale fits every panel
    plot_reference(next(iter(runs.values())), axes[0])
    axes[0].set_title(f"Reference {ref} and tracking error per feedforward", loc="left",
                      fontsize=10)
    for ax, label in zip(axes[1:], fb + ff):
        row, note = stats.get(label), ""
        if row is not None and row.n_seeds > 1:
            mae = row.mae[ref]
            note = (f" (seed 0 of {row.n_seeds}; table: {mae.mean * UM:.3f} ± "
                    f"{mae.std * UM:.3f} µm over the seeds)")
        plot_tracking_error(runs[label], ax, label=label, color=colors[label], note=note)
    for ax in axes[:-1]:
        ax.set_xlabel("")
    return fig


def feedforward_figure(replays: dict, ref: str) -> Figure:
    """The feedforward forces on ``ref``: the LIP's (else the first feedforward's) u_ff in N,
    then every other feedforward as its difference from it, on one shared scale."""
    runs = {label: r[ref] for label, r in replays.items()}
    colors = {label: color(i) for i, label in enumerate(runs)}
    ff = [label for label, run in runs.items() if np.any(run.u_ff)]
    if not ff:
        raise ValueError("feedforward_figure: no run has a feedforward")
    base = "LIP" if "LIP" in ff else ff[0]
    others = [label for label in ff if label != base]
    fig, axes = _panels(1 + len(others), [1.2] + [1.0] * len(others))
    for ax in axes[2:]:
        ax.sharey(axes[1])
    plot_feedforward(runs[base], axes[0], label=f"{base} feedforward on {ref}",
                     color=colors[base])
    for ax, label in zip(axes[1:], others):
        plot_feedforward(runs[label], ax, base=runs[base], label=f"{label} minus {base}",
                         color=colors[label])
    for ax in axes[:-1]:
        ax.set_xlabel("")
    return fig
