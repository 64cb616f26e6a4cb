"""The diagnosis's figures: the residual against position, velocity and time, its spectrum,
the loop re-simulated on the measured reference and the encoder-origin scan."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from experiments.plots import MM, PALETTE, UM, _ax, _figure, _legend_right, _panels

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
