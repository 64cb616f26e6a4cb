"""The mechanism study's figure (``figures/force_beyond.png``), drawn from the cells it
computed."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from experiments.studies.mechanism.report import zero_label
from experiments.studies.mechanism.result import CellResult
from experiments.studies.mechanism.settings import MechanismSettings


def draw(results: list[CellResult], settings: MechanismSettings, path: Path) -> None:
    """Per case (columns): the static force against position, beyond the range shaded: top,
    the true force, the LIP and the two lambdas; bottom, the lambda = 0 fit split into
    theta . T minus the LIP, the network's linear part and its remainder."""
    import matplotlib.pyplot as plt

    from experiments import plots

    first = {}
    for r in results:
        first.setdefault(r.case, r)
    fig, axes = plt.subplots(2, len(first), figsize=(5 * len(first), 7), squeeze=False,
                             sharex=True)
    for j, (case, r) in enumerate(first.items()):
        y = np.asarray(r.y) * 1e3
        lip = np.asarray(r.lip_static)
        f0 = next(f for f in r.fits if f.draw == 0 and f.lam == 0.0)
        f1 = next(f for f in r.fits if f.draw == 0 and f.lam == settings.lam)
        tot = {k: np.asarray(f.static.physical) + np.asarray(f.static.network)
               for k, f in (("0", f0), ("1", f1))}
        top, bottom = axes[0, j], axes[1, j]
        top.plot(y, r.truth, color=plots.PALETTE[0], ls="--", label="true force")
        top.plot(y, lip, color=plots.PALETTE[7], label="LIP")
        z = zero_label(settings)
        top.plot(y, tot["0"], color=plots.PALETTE[4], label=f"PGNN {z}")
        top.plot(y, tot["1"], color=plots.PALETTE[5], label=f"PGNN λ = {settings.lam:g}")
        bottom.plot(y, np.asarray(f0.static.physical) - lip, color=plots.PALETTE[1],
                    label=f"{z}: θ·T − LIP")
        bottom.plot(y, f0.static.network_linear, color=plots.PALETTE[2],
                    label="network, linear part")
        bottom.plot(y, f0.static.remainder, color=plots.PALETTE[3],
                    label="network remainder")
        bottom.plot(y, np.asarray(r.truth) - lip, color=plots.PALETTE[0], ls="--",
                    label="true − LIP")
        limit = r.position_limit_m * 1e3
        for ax in (top, bottom):
            for side in (-1, 1):
                ax.axvspan(side * limit, side * y.max(), color=plots.PALETTE[4], alpha=0.08)
            ax.grid(alpha=0.3)
            ax.set_ylabel("force [N]")
        top.set_title(f"{case}, record {r.record}: static force at rest", fontsize=9,
                      loc="left")
        bottom.set_title(f"{zero_label(settings)} fit, split", fontsize=9, loc="left")
        bottom.set_xlabel("position [mm]")
        top.legend(fontsize=7, loc="upper left")
        bottom.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    plots.save(fig, path)
