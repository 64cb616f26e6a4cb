"""The extrapolation study's figures, beside it (:mod:`experiments.studies.extrapolation.study`):
they draw its summary, the fitted models' histories and the force split it predicted once
(:class:`experiments.results.ForceSplit`), in the house style of :mod:`experiments.plots`, and
run no model."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from matplotlib.figure import Figure

from clm_sim.plant import THETA_NAMES, THETA_UNITS
from experiments.plots import MM, PALETTE, UM, _ax, _figure, _legend_right, _panels, color

from experiments.studies.extrapolation.result import (
    FEEDBACK, LIP, SEQUENTIAL, ExtrapolationResult, variant_key, variant_label)

if TYPE_CHECKING:
    from experiments.results import ForceSplit


def variant_colors(summary: ExtrapolationResult) -> dict[str, str]:
    """One colour per variant of the study, the same in every figure."""
    keys = [FEEDBACK, LIP, SEQUENTIAL] + summary.lam_keys
    return {k: color(i) for i, k in enumerate(keys)}


def plot_theta_history(models: dict, lip_theta: dict, name: str, keys: list[str], ax=None, *,
                       colors: dict | None = None):
    """θ_phy[name] / θ_LIP[name] over the LM iterations of the first seed of each variant."""
    ax = _ax(ax)
    ref = lip_theta[name] if lip_theta[name] else 1.0
    for i, key in enumerate(keys):
        hist = models[key][0].history_
        ax.plot([h.iteration for h in hist], [h.theta[name] / ref for h in hist],
                color=(colors or {}).get(key, color(i)), lw=1.2, label=variant_label(key))
    ax.set_title(f"{name} (θ_LIP = {lip_theta[name]:.4g} {THETA_UNITS[name]})", fontsize=9)
    ax.set_xlabel("LM iteration [–]")
    ax.set_ylabel(f"{name} / {name}_LIP [–]")
    ax.grid(alpha=0.3)
    return ax


def theta_figure(summary: ExtrapolationResult, models: dict) -> Figure:
    """θ_phy relative to θ_LIP over the iterations, one panel per parameter, one line per λ."""
    keys = summary.lam_keys
    colors = variant_colors(summary)
    fig = _figure(11, 6.5)
    axes = fig.subplots(2, 2, sharex=True)
    for ax, name in zip(axes.flat, THETA_NAMES):
        plot_theta_history(models, summary.theta_lip, name, keys, ax, colors=colors)
    for ax in axes[0]:
        ax.set_xlabel("")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside right upper", fontsize=8, frameon=False)
    fig.suptitle("θ_phy over the Levenberg–Marquardt iterations (seed 0)", fontsize=10)
    return fig


def cost_figure(summary: ExtrapolationResult, models: dict) -> Figure:
    """Data-fit term (N²) and deviation term (N²) over the iterations, per λ and sequential."""
    colors = variant_colors(summary)
    fig = _figure(12, 4.2)
    ax_d, ax_p = fig.subplots(1, 2, sharex=True)
    for key in [SEQUENTIAL] + summary.lam_keys:
        hist = models[key][0].history_
        it = [h.iteration for h in hist]
        ax_d.plot(it, [h.data for h in hist], color=colors[key], lw=1.2,
                  ls="--" if key == SEQUENTIAL else "-", label=variant_label(key))
        dev = [h.deviation for h in hist]
        if max(dev) > 0:
            ax_p.plot(it, dev, color=colors[key], lw=1.2)
    ax_d.axhline(summary.lip_residual_rms_n ** 2, color=colors[LIP], lw=1, ls=":",
                 label="LIP (all samples)")
    ax_d.set_title("data-fit term: mean squared force error", fontsize=9)
    ax_p.set_title("deviation term (θ−θ_LIP)ᵀΛ(θ−θ_LIP)", fontsize=9)
    for ax in (ax_d, ax_p):
        ax.set_yscale("log")
        ax.set_xlabel("LM iteration [–]")
        ax.set_ylabel("cost [N²]")
        ax.grid(alpha=0.3, which="both")
    fig.legend(*ax_d.get_legend_handles_labels(), loc="outside right upper", fontsize=8,
               frameon=False)
    return fig


def split_figure(summary: ExtrapolationResult, split: ForceSplit) -> Figure:
    """The feedforward on ``split.reference`` split into its physical part (minus the LIP force:
    what the drift of θ_phy changes) and its network part, and their sum against the true plant
    force, for λ = 0, the paper's λ and sequential (one seed, as the study predicted them);
    shaded: the samples beyond the training range."""
    keys = [variant_key(0.0), variant_key(summary.paper_lam), SEQUENTIAL]
    colors = variant_colors(summary)
    limit = summary.ranges[summary.inside].position_m
    r, lip_force, beyond = split.r, split.lip_force, split.beyond
    t = np.arange(len(r)) * split.ts
    fig, axes = _panels(4, [0.8, 1, 1, 1], width=11)
    axes[0].plot(t, r * MM, "k", lw=1)
    for sign in (1, -1):
        axes[0].axhline(sign * limit * MM, color=PALETTE[4], lw=0.8, ls=":")
    axes[0].set_ylabel("r [mm]")
    axes[0].set_title(f"{split.reference}; dotted: training position range; shaded: position, "
                      f"velocity or acceleration outside the training range", loc="left",
                      fontsize=9)
    for key in keys:
        phys, net = split.parts[key]
        kw = {"color": colors[key], "lw": 0.9, "label": variant_label(key)}
        axes[1].plot(t, phys - lip_force, **kw)
        axes[2].plot(t, net, **kw)
        axes[3].plot(t, phys + net - lip_force, **kw)
    if split.truth is not None:
        axes[3].plot(t, split.truth - lip_force, color=PALETTE[7], ls="--", lw=0.9,
                     label="true plant force")
    titles = ["physical part θ_phy·filt(T) minus the LIP force", "network part f_NN",
              "whole model minus the LIP force"]
    for ax, title in zip(axes[1:], titles):
        ax.fill_between(t, 0, 1, where=beyond, color=PALETTE[4], alpha=0.1,
                        transform=ax.get_xaxis_transform())
        ax.set_title(title, loc="left", fontsize=9)
        ax.set_ylabel("force [N]")
        ax.grid(alpha=0.3)
        # The Coulomb and acceleration steps of the physical part would hide the rest.
        lo, hi = np.percentile(np.concatenate([ln.get_ydata() for ln in ax.lines]), [0.5, 99.5])
        pad = 0.15 * (hi - lo + 1e-9)
        ax.set_ylim(lo - pad, hi + pad)
    for ax in axes:
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("t [s]")
    fig.legend(*axes[3].get_legend_handles_labels(), loc="outside right upper", fontsize=8,
               frameon=False)
    return fig


def plot_mae_vs_lambda(summary: ExtrapolationResult, ref: str, ax=None, *, marker: str = "o",
                       color: str = PALETTE[5]):
    """MAE (µm, mean ± std over seeds) on ``ref`` against λ; λ = 0 is drawn one decade left
    of the smallest positive λ; the LIP and the sequential PGNN as horizontal lines."""
    ax = _ax(ax)
    lams = summary.lams
    positive = [x for x in lams if x > 0]
    zero_at = min(positive) / 10 if positive else 1e-4
    xs = [x if x > 0 else zero_at for x in lams]
    v = summary.variants
    mean = [v[key].mae[ref].mean * UM for key in summary.lam_keys]
    std = [v[key].mae[ref].std * UM for key in summary.lam_keys]
    ax.errorbar(xs, mean, yerr=std, marker=marker, capsize=3, color=color,
                label=f"PGNN on {ref}")
    ax.axhline(v[LIP].mae[ref].mean * UM, color=color, ls=":", lw=1,
               label=f"LIP on {ref}")
    ax.axhline(v[SEQUENTIAL].mae[ref].mean * UM, color=color, ls="--", lw=1,
               label=f"sequential on {ref}")
    ax.set_xscale("log")
    ax.set_xticks(xs, [f"{x:g}" for x in lams])
    ax.minorticks_off()
    ax.set_xlabel("regularization weight λ [–] (λ = 0 at the left edge)")
    ax.set_ylabel("MAE [µm]")
    ax.grid(alpha=0.3, which="both")
    return ax


def mae_vs_lambda_figure(summary: ExtrapolationResult) -> Figure:
    """MAE against λ on every reference of the study, one colour per reference."""
    fig = _figure(8.5, 4.2)
    ax = fig.subplots()
    for i, ref in enumerate(summary.references):
        plot_mae_vs_lambda(summary, ref, ax, marker="osd^v"[i % 5], color=color(i + 5))
    _legend_right(ax)
    return fig
