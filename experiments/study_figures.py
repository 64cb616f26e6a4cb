"""Figures of the extrapolation study (``experiments.study``): PNG files, one idea each."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from clm_sim.plant import THETA_NAMES  # noqa: E402


def _lambda_keys(summary):
    return [f"lambda={lam:g}" for lam in summary["lambdas"]]


def _colors(n):
    return plt.cm.viridis(np.linspace(0.0, 0.9, n))


def theta_training(summary, models, path: Path) -> None:
    """theta_phy / theta_LIP over the iterations, one panel per parameter, one line per lambda."""
    lip = summary["theta_lip"]
    fig, axes = plt.subplots(2, 2, figsize=(10, 6), sharex=True)
    keys = _lambda_keys(summary)
    for key, c in zip(keys, _colors(len(keys))):
        hist = models[key][0].history_
        it = [h["iteration"] for h in hist]
        for ax, name in zip(axes.flat, THETA_NAMES):
            ref = lip[name] if lip[name] else 1.0
            ax.plot(it, [h["theta"][name] / ref for h in hist], color=c, label=key, lw=1.2)
    for ax, name in zip(axes.flat, THETA_NAMES):
        ax.set_title(f"{name} / {name}_LIP")
        ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("LM iteration")
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def cost_terms(summary, models, path: Path) -> None:
    """Data-fit term (N²) and parameter-deviation term (N²) over the iterations per lambda."""
    fig, (ax_d, ax_p) = plt.subplots(1, 2, figsize=(11, 4))
    keys = _lambda_keys(summary)
    for key, c in zip(keys, _colors(len(keys))):
        hist = models[key][0].history_
        it = [h["iteration"] for h in hist]
        ax_d.plot(it, [h["data"] for h in hist], color=c, label=key)
        dev = [h["deviation"] for h in hist]
        if max(dev) > 0:
            ax_p.plot(it, dev, color=c, label=key)
    seq = models["sequential"][0].history_
    ax_d.plot([h["iteration"] for h in seq], [h["data"] for h in seq], "k--", label="sequential")
    ax_d.axhline(summary["lip_residual_rms_n"] ** 2, color="r", lw=0.8, ls=":",
                 label="LIP (all samples)")
    ax_d.set_yscale("log")
    ax_d.set_title("data-fit term: mean squared error [N²]")
    ax_p.set_yscale("log")
    ax_p.set_title("deviation term (θ−θ_LIP)ᵀΛ(θ−θ_LIP) [N²]")
    for ax in (ax_d, ax_p):
        ax.set_xlabel("LM iteration")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def split(summary, models, lip, ref, r, ts, path: Path, truth=None) -> None:
    """Feedforward on ``ref`` split into physical and network parts, for lambda = 0, the paper's
    lambda and sequential (seed 0): the physical part minus the LIP's (what the drift of theta_phy
    changes) and the network part (what the network adds), with their sum."""
    keys = ["lambda=0", f"lambda={summary['paper_lambda']:g}", "sequential"]
    from experiments.study import beyond_range

    limit = summary["ranges"][summary["inside"]]["position_m"]
    t = np.arange(len(r)) * ts
    lip_force = lip.predict(y=r, ts=ts)
    fig, axes = plt.subplots(4, 1, figsize=(10, 9), sharex=True)
    axes[0].plot(t, r * 1e3, "k", lw=1)
    axes[0].axhline(limit * 1e3, color="r", lw=0.8, ls=":")
    axes[0].axhline(-limit * 1e3, color="r", lw=0.8, ls=":")
    axes[0].set_ylabel("r [mm]")
    beyond = beyond_range(lip.features, r, ts, summary["ranges"][summary["inside"]])
    for key in keys:
        phys, net = models[key][0].predict_parts(y=r, ts=ts)
        axes[1].plot(t, phys - lip_force, lw=0.9, label=key)
        axes[2].plot(t, net, lw=0.9, label=key)
        axes[3].plot(t, phys + net - lip_force, lw=0.9, label=key)
    if truth is not None:
        axes[3].plot(t, truth - lip_force, "k--", lw=0.8, label="true plant force")
        axes[3].legend(fontsize=7, loc="upper right")
    titles = ["physical part θ_phy·T minus LIP force [N]", "network part f_NN [N]",
              "whole model (and true plant force) minus LIP force [N]"]
    for ax, title in zip(axes[1:], titles):
        ax.fill_between(t, 0, 1, where=beyond, color="r", alpha=0.08,
                        transform=ax.get_xaxis_transform())
        ax.set_title(title, fontsize=9)
        ax.grid(alpha=0.3)
        # The Coulomb and acceleration steps of the physical part would hide the rest.
        lo, hi = np.percentile(np.concatenate([ln.get_ydata() for ln in ax.lines]), [0.5, 99.5])
        pad = 0.15 * (hi - lo + 1e-9)
        ax.set_ylim(lo - pad, hi + pad)
    axes[1].legend(fontsize=7, loc="upper right")
    axes[0].set_title(f"{ref}; shaded: position, velocity or acceleration outside the training "
                      f"range", fontsize=9)
    axes[-1].set_xlabel("t [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def tracking(summary, runs, ref, path: Path) -> None:
    """Tracking error on ``ref`` for LIP, sequential, lambda = 0 and the paper's lambda."""
    keys = ["LIP", "sequential", "lambda=0", f"lambda={summary['paper_lambda']:g}"]
    fig, ax = plt.subplots(figsize=(10, 4))
    for key in keys:
        run = runs[key][ref]
        ax.plot(run.t, run.e * 1e6, lw=0.7, label=key)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("e = r − y [µm]")
    ax.set_title(f"Tracking error on {ref} (seed 0)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def mae_vs_lambda(summary, path: Path) -> None:
    """MAE (mean ± std over seeds) against lambda; lambda = 0 drawn at the left edge."""
    lams = summary["lambdas"]
    positive = [x for x in lams if x > 0]
    zero_at = min(positive) / 10 if positive else 1e-4
    xs = [x if x > 0 else zero_at for x in lams]
    fig, ax = plt.subplots(figsize=(7, 4))
    v = summary["variants"]
    for ref, marker in zip([summary["inside"], *summary["outside"]], "osd^v"):
        mean = [v[f"lambda={x:g}"]["mae"][ref]["mean"] * 1e6 for x in lams]
        std = [v[f"lambda={x:g}"]["mae"][ref]["std"] * 1e6 for x in lams]
        line = ax.errorbar(xs, mean, yerr=std, marker=marker, capsize=3, label=f"PGNN on {ref}")
        color = line[0].get_color()
        ax.axhline(v["LIP"]["mae"][ref]["mean"] * 1e6, color=color, ls=":", lw=1,
                   label=f"LIP on {ref}")
        ax.axhline(v["sequential"]["mae"][ref]["mean"] * 1e6, color=color, ls="--", lw=1,
                   label=f"sequential on {ref}")
    ax.set_xscale("log")
    ax.set_xticks(xs)
    ax.set_xticklabels([f"{x:g}" for x in lams])
    ax.set_xlabel("λ (λ = 0 at the left edge)")
    ax.set_ylabel("MAE [µm]")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def draw(summary, study, lip, refs, models, runs, ts, folder: Path, truth=None) -> None:
    """Every figure of the report into ``folder``."""
    folder = Path(folder)
    theta_training(summary, models, folder / "theta_training.png")
    cost_terms(summary, models, folder / "cost_terms.png")
    for ref in summary["outside"]:
        split(summary, models, lip, ref, refs[ref], ts, folder / f"split_{ref}.png",
              None if truth is None else truth[ref])
    for ref in refs:
        tracking(summary, runs, ref, folder / f"tracking_{ref}.png")
    mae_vs_lambda(summary, folder / "mae_vs_lambda.png")
