"""Figures of a run: tracking error per feedforward on each reference, and the feedforward signals."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def tracking_errors(replays: dict[str, dict], ref: str, path: Path) -> None:
    """``replays[label][ref]`` is a Run; one panel, one line per feedforward, error in um."""
    fig, (ax_r, ax_e) = plt.subplots(2, 1, figsize=(9, 6), sharex=True,
                                     gridspec_kw={"height_ratios": [1, 3]})
    first = next(iter(replays.values()))[ref]
    ax_r.plot(first.t, first.r * 1e3, color="k", lw=1)
    ax_r.set_ylabel("r [mm]")
    for label, runs in replays.items():
        run = runs[ref]
        ax_e.plot(run.t, run.e * 1e6, lw=0.8, label=label)
    ax_e.set_ylabel("e = r - y [µm]")
    ax_e.set_xlabel("t [s]")
    ax_e.legend(fontsize=8, loc="upper right")
    ax_e.grid(alpha=0.3)
    ax_r.set_title(f"Tracking error on {ref}")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def feedforward_signals(replays: dict[str, dict], ref: str, path: Path) -> None:
    """The feedforward force of each model on one reference, in N."""
    fig, ax = plt.subplots(figsize=(9, 4))
    for label, runs in replays.items():
        run = runs[ref]
        if abs(run.u_ff).max() > 0:
            ax.plot(run.t, run.u_ff, lw=0.8, label=label)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("u_ff [N]")
    ax.set_title(f"Feedforward on {ref}")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
