"""The house style of clm-sim's figures and the figures of the library: runs, sweeps, the
diagnosis and the profiles. A study's own figures sit beside it
(:mod:`experiments.studies.extrapolation.figures`, :mod:`experiments.studies.failure_map.figures`)
and draw with the helpers here. Figures take
results and never run a model (no ``predict``): whoever computed a result hands it over.

Two kinds of functions. ``plot_*(..., ax=None) -> Axes`` draw one panel on ``ax`` (default: the
current pyplot axes, for notebooks). ``*_figure(...) -> Figure`` compose a whole figure from
panels without pyplot, so writing files needs no backend; :func:`save` writes one atomically.
No backend is chosen here (the CLI picks Agg). One palette (Okabe–Ito, colour-blind safe), units
on every axis, legends outside the data.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter
from matplotlib.transforms import offset_copy

from clm_sim.outdir import atomic_write
from experiments.stats.seeds import series


# Okabe & Ito's colour-blind-safe set (yellow left out: unreadable on white), then grey, and
# Tol's wine and olive (apart from every colour before them).
PALETTE = ("#000000", "#E69F00", "#56B4E9", "#009E73", "#D55E00", "#0072B2", "#CC79A7",
           "#999999", "#882255", "#999933")
UM, MM = 1e6, 1e3  # m -> µm, m -> mm

# Swept key path (list indices written [*]) -> quantity, its symbol (None: the quantity names
# itself), unit, factor from the SI value.
KEY_LABELS = {
    "plant.encoder_resolution": ("encoder resolution", "q", "µm", 1e6),
    "plant.mass": ("mass", "m", "kg", 1.0),
    "plant.viscous": ("viscous friction", "fv", "N·s/m", 1.0),
    "plant.coulomb": ("Coulomb friction", "fc", "N", 1.0),
    "plant.stiffness": ("stiffness", "fk", "N/m", 1.0),
    "plant.substeps": ("sub-steps per sample", None, "–", 1.0),
    "controller.crossover_hz": ("PID crossover frequency", "f_c", "Hz", 1.0),
    "feedforwards[*].lambda": ("regularization weight", "λ", "–", 1.0),
    "feedforwards[*].hidden": ("neurons", "n_l", "–", 1.0),
    "training.dither.std_n": ("dither std", None, "N", 1.0),
    "training.dither.hold_samples": ("dither hold", None, "samples", 1.0),
    "training.repeats": ("training repeats", None, "–", 1.0),
    "ts": ("sample time", "ts", "s", 1.0),
    "seed": ("seed", None, "–", 1.0),
}


def color(i: int) -> str:
    """The ``i``-th colour of the palette (cycling)."""
    return PALETTE[i % len(PALETTE)]


def _key(key: str) -> tuple[str, str | None, str, float]:
    """Quantity, symbol, unit and factor of a swept key path; an unknown key names itself, in
    the config's (SI) units."""
    return KEY_LABELS.get(re.sub(r"\[\d+\]", "[*]", key), (key, None, "SI", 1.0))


def key_label(key: str) -> tuple[str, float]:
    """``(axis label with unit, factor from SI)`` of a swept key path."""
    quantity, symbol, unit, factor = _key(key)
    return f"{quantity}{' ' + symbol if symbol else ''} [{unit}]", factor


def _describe(key: str, value) -> str:
    """``λ = 0.01``, ``q = 0.1 µm``: a swept key and its value, as a legend names a series."""
    quantity, symbol, unit, factor = _key(key)
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = f"{value * factor:g}"
    return f"{symbol or quantity} = {value}" + ("" if unit in ("–", "SI") else f" {unit}")


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


# ----------------------------------------------------------------------------- sweeps

def plot_mae_vs_key(rows: list[dict], swept: list[str], x: str, ref: str, ax=None):
    """MAE (µm) on ``ref`` against swept key ``x``: one line per series
    (:func:`experiments.stats.seeds.series`), the spread over seeds as a band, or with more than
    three series as error bars set slightly apart (overlapping bands hide each other)."""
    ax = _ax(ax)
    data = {name: by_x for (name, r), by_x in series(rows, swept, x, _describe).items()
            if r == ref}
    label, factor = key_label(x)
    xs = [row.value(x) for row in rows]
    numeric = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in xs)
    cats = None if numeric else list(dict.fromkeys(map(str, xs)))
    if numeric:
        vals = np.array(sorted(set(xs)), float) * factor
        positive = vals[vals > 0]
        if len(positive) and positive.max() / positive.min() > 20:
            ax.set_xscale("symlog" if (vals <= 0).any() else "log",
                          **({"linthresh": positive.min()} if (vals <= 0).any() else {}))
            ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        elif len(vals) <= 12:
            ax.set_xticks(vals, [f"{v:g}" for v in vals])
    else:
        ax.set_xticks(range(len(cats)), cats)
    bands = len(data) <= 3
    means = []
    for i, (name, by_x) in enumerate(data.items()):
        keys = sorted(by_x) if numeric else sorted(by_x, key=lambda v: cats.index(str(v)))
        pos = (np.array(keys, float) * factor if numeric
               else np.array([cats.index(str(k)) for k in keys], float))
        mean = np.array([by_x[k][0] for k in keys]) * UM
        spread = np.array([by_x[k][1] for k in keys]) * UM
        means.extend(mean)
        if bands:
            ax.plot(pos, mean, marker="o", ms=3, lw=1.2, color=color(i), label=name)
            ax.fill_between(pos, np.maximum(mean - spread, 1e-6), mean + spread,
                            color=color(i), alpha=0.2, lw=0)
        else:  # 4 points apart per series, in display space (linear and log axes alike)
            shift = offset_copy(ax.transData, fig=ax.figure, units="points",
                                x=4.0 * (i - (len(data) - 1) / 2))
            bars = ax.errorbar(pos, mean, yerr=spread, marker="o", ms=3, lw=1.0, capsize=2,
                               color=color(i), label=name)
            for artist in bars.get_children():  # drawn shifted, scaled on the data
                artist.set_transform(shift)
    if not bands:
        ax.margins(x=0.08)  # room for the shifted bars at both ends
    if means and min(means) > 0 and max(means) / min(means) > 20:
        ax.set_yscale("log")
        ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))  # 0.2 not 2x10^-1
        ax.yaxis.set_minor_formatter(FuncFormatter(
            lambda v, _: f"{v:g}" if f"{v:.0e}"[0] in "25" else ""))
    ax.set_xlabel(label)
    ax.set_ylabel(f"MAE on {ref} [µm]")
    ax.grid(alpha=0.3, which="both")
    return ax


def plot_mae_dots(rows: list[dict], swept: list[str], x: str, ref: str, ax=None):
    """MAE (µm) on ``ref``, one line of the panel per series, one marker per value of the swept
    key ``x`` (a few values), the spread over seeds as a horizontal bar. For many series over
    few x values: lines between two x values only cross each other."""
    ax = _ax(ax)
    data = {name: by_x for (name, r), by_x in series(rows, swept, x, _describe).items()
            if r == ref}
    label, factor = key_label(x)
    values = list({v: None for by_x in data.values() for v in by_x})
    numeric = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)
    values = sorted(values) if numeric else values
    names = list(data)
    for j, xv in enumerate(values):
        offset = 0.25 * (j - (len(values) - 1) / 2)
        pos = [i + offset for i, name in enumerate(names) if xv in data[name]]
        stats = [data[name][xv] for name in names if xv in data[name]]
        ax.errorbar([m * UM for m, _, _ in stats], pos, xerr=[sp * UM for _, sp, _ in stats],
                    fmt="o", ms=4, capsize=2, lw=1.0, color=color(j),
                    label=f"{label.split(' [')[0]} = {_fmt_value(xv, factor)}")
    ax.set_yticks(range(len(names)), names, fontsize=8)
    ax.invert_yaxis()
    ax.set_xlabel(f"MAE on {ref} [µm]")
    ax.grid(alpha=0.3, axis="x")
    return ax


def _fmt_value(value, factor: float) -> str:
    return f"{value * factor:g}" if isinstance(value, (int, float)) else str(value)


def mae_vs_key_figure(rows: list[dict], swept: list[str], x: str) -> Figure:
    """MAE against swept key ``x``, one panel per reference, the legend below the panels. With
    more than three series over at most three values of ``x``, a dot plot per series
    (:func:`plot_mae_dots`) instead of lines."""
    refs = rows[0].references
    n_series = len({name for name, _ in series(rows, swept, x, _describe)})
    if n_series > 3 and len({str(row.value(x)) for row in rows}) <= 3:
        fig = _figure(4.6 * len(refs) + 2.4, 0.9 + 0.42 * n_series)
        axes = np.atleast_1d(fig.subplots(1, len(refs), sharey=True))
        for ax, ref in zip(axes, refs):
            plot_mae_dots(rows, swept, x, ref, ax)
        fig.suptitle(f"MAE per feedforward and {_key(x)[0]} (mean and spread over seeds)",
                     fontsize=10)
        handles, labels = axes[0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="outside lower center", ncol=len(labels), fontsize=8,
                   frameon=False)
        return fig
    fig = _figure(5.2 * len(refs), 4.6)
    axes = np.atleast_1d(fig.subplots(1, len(refs)))
    for ax, ref in zip(axes, refs):
        plot_mae_vs_key(rows, swept, x, ref, ax)
    fig.suptitle(f"MAE against {_key(x)[0]} (mean and spread over seeds)",
                 fontsize=10)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=min(3, len(labels)),
               fontsize=8, frameon=False)
    return fig


# ----------------------------------------------------------------------------- diagnosis

def plot_residual_against(res, x: str, ax=None, *, color: str = PALETTE[5]):
    """The filtered force residual (N) of a diagnosis ``Residual`` against ``x``: position,
    velocity or acceleration, over the samples the diagnosis fits."""
    ax = _ax(ax)
    i = res.idx
    values, label = {"position": (res.y[i] * MM, "position y [mm]"),
                     "velocity": (res.v_filtered[i], "velocity v [m/s]"),
                     "acceleration": (res.filter(res.a)[i], "acceleration a [m/s²]")}[x]
    ax.plot(values, res.z, ".", ms=1.0, alpha=0.4, color=color, rasterized=True)
    ax.set_xlabel(label)
    ax.set_ylabel("force residual [N]")
    return ax


def plot_residual_time(res, ax=None, *, label: str = "model", color: str = PALETTE[7]):
    """The filtered force residual (N) over time on one record; the title names ``label`` and
    its RMS. Model and extended model go in two panels on one scale (:func:`residual_time_figure`):
    drawn on top of each other, the later curve's spikes hide the other's."""
    ax = _ax(ax)
    ax.plot(res.t, res.filtered, lw=0.5, color=color)
    ax.set_xlabel("time t [s]")
    ax.set_ylabel("force residual [N]")
    rms = float(np.sqrt(np.mean(np.square(res.filtered))))
    ax.set_title(f"{label}: RMS {rms:.3g} N", loc="left", fontsize=9, color=color)
    ax.grid(alpha=0.3)
    return ax


def residual_time_figure(before, after) -> Figure:
    """The force residual over time, model above extended model, on one shared scale."""
    fig, (ax, ax2) = _panels(2, [1.0, 1.0])
    ax2.sharey(ax)
    plot_residual_time(before, ax, label="model")
    plot_residual_time(after, ax2, label="extended model", color=PALETTE[4])
    ax.set_xlabel("")
    return fig


def plot_residual_spectrum(before, after, ax=None):
    """Amplitude spectral density (N/√Hz) of the force residual on one record, model against
    extended model: what the extension removed, frequency by frequency."""
    ax = _ax(ax)
    for res, label, c in ((before, "model", PALETTE[7]), (after, "extended model", PALETTE[4])):
        f, a = res.spectrum()
        ax.loglog(f[1:], a[1:], lw=0.8, color=c, label=label)
    ax.set_xlabel("frequency f [Hz]")
    ax.set_ylabel("residual ASD [N/√Hz]")
    _legend_right(ax)
    return ax


def diagnosis_figures(d) -> dict[str, tuple[Figure, str]]:
    """The figures of a diagnosis report: ``{file name: (figure, caption)}``."""
    before, after = d.signals.val_before, d.signals.val_after
    out = {}
    fig = _figure(12, 3.8)
    axes = fig.subplots(1, 3, sharey=True)
    for ax, x in zip(axes, ("position", "velocity", "acceleration")):
        plot_residual_against(d.estimation, x, ax)
    for ax in axes[1:]:
        ax.set_ylabel("")
    fig.suptitle("Force residual u − model inverse dynamics (filtered; samples whose friction "
                 "direction is unknown left out)", fontsize=10)
    out["residual.png"] = (fig, "Residual of the model against position, velocity and "
                                "acceleration (estimation record)")
    out["residual_time.png"] = (residual_time_figure(before, after),
                                "Residual over time on the validation record: the model above, "
                                "the extended model below, on one scale")
    fig = _figure(8, 4)
    plot_residual_spectrum(before, after, fig.subplots())
    out["spectrum.png"] = (fig, "Residual spectrum on the validation record (Welch, "
                                "unfiltered): model against extended model")
    s = d.signals
    if s.e_measured is not None:
        # Measured and re-simulated errors nearly coincide: drawn together they hide each other,
        # so the measured error has its own panel and each model its difference from it.
        fig, axes = _panels(3, [1.0, 1.0, 1.0])
        axes[2].sharey(axes[1])
        axes[0].plot(s.t, s.e_measured * UM, lw=0.6, color=PALETTE[0])
        axes[0].set_title("measured tracking error", loc="left", fontsize=9, color=PALETTE[0])
        axes[0].set_ylabel("e [µm]")
        for ax, e, label, c in ((axes[1], s.e_before, "model", PALETTE[7]),
                                (axes[2], s.e_after, "extended model", PALETTE[4])):
            diff = (e - s.e_measured) * UM
            ax.plot(s.t, diff, lw=0.6, color=c)
            ax.set_title(f"re-simulated with the {label} − measured: RMS "
                         f"{float(np.sqrt(np.mean(diff ** 2))):.3g} µm", loc="left", fontsize=9,
                         color=c)
            ax.set_ylabel("Δe [µm]")
        for ax in axes:
            ax.grid(alpha=0.3)
        axes[2].set_xlabel("time t [s]")
        out["tracking.png"] = (fig, "Loop re-simulated on the measured reference (validation)")
    if s.origin_scan is not None:
        fig = _figure(7, 3.5)
        plot_origin_scan(*s.origin_scan, ax=fig.subplots())
        out["origin.png"] = (fig, "Encoder origin of the validation record: residual RMS of the "
                                  "extended model on the registration part against the origin "
                                  "shift, over one period of its strongest periodic effect")
    return out


def plot_origin_scan(delta: float, shifts: np.ndarray, rms: np.ndarray, ax=None):
    """Residual RMS (N) against the origin shift (mm), the registered shift marked."""
    ax = ax or _figure(7, 3.5).subplots()
    ax.plot(shifts * 1e3, rms, color=PALETTE[0], marker=".", ms=3, lw=0.8)
    ax.axvline(0.0, color=PALETTE[7], lw=0.8, ls=":", label="origin of the estimation record")
    ax.axvline(delta * 1e3, color=PALETTE[4], lw=1.0, ls="--",
               label=f"registered: {delta * 1e3:+.4g} mm")
    ax.set_xlabel("origin shift δ [mm]")
    ax.set_ylabel("residual RMS [N]")
    _legend_right(ax)
    return ax
