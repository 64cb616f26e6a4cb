"""A sweep's figures: MAE against a swept key, one series per feedforward (and per value of the
other swept keys), the spread over the swept seeds (:func:`experiments.stats.seeds.series`)."""

from __future__ import annotations

import re

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter
from matplotlib.transforms import offset_copy

from experiments.plots import UM, _ax, _figure, color
from experiments.stats.seeds import series
from experiments.table import Row

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


def plot_mae_vs_key(rows: list[Row], swept: list[str], x: str, ref: str, ax=None):
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


def plot_mae_dots(rows: list[Row], swept: list[str], x: str, ref: str, ax=None):
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


def mae_vs_key_figure(rows: list[Row], swept: list[str], x: str) -> Figure:
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
