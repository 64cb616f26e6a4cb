"""The extrapolation study: why a PGNN trained without regularization (lambda = 0) extrapolates
badly, and what lambda changes. ``clm-sim study CONFIG --out DIR`` writes ``report.md``,
``study.json`` and ``figures/*.png``.

The config is an experiment config (plant, controller, references, training, features; its
``feedforwards``, ``replay`` and ``data``, which it does not use, are refused) plus a ``study:``
section (:class:`StudySettings`). One training run and one LIP are shared by every model; per
lambda of the sweep a simultaneous PGNN is trained per seed, beside a sequential PGNN, and all
are replayed on the training reference (r1) and on the reference that leaves the training range
(r2).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import ClassVar
from pathlib import Path

import numpy as np

from clm_sim.errors import UserError
from clm_sim.features import TrainingRange
from clm_sim.plant import THETA_NAMES, THETA_UNITS
from clm_sim.schema import build, load_yaml, to_plain
from controllers.pgnn_settings import FILE_KEYS, PGNNSettings
from experiments import plots
from experiments.config import ExperimentConfig, FeedforwardSpec, in_file, resolved
from experiments.results import BeyondRange, ForceSplit
from experiments.runner import preflight
from experiments.stats.paired import t_interval
from experiments.studies.extrapolation import figures
from experiments.studies.extrapolation.result import (
    FEEDBACK, LIP, SEQUENTIAL, Costs, ExtrapolationResult, NetworkParts, Spread, Trained,
    Variant, variant_key, variant_label)
from experiments.studies.kinds import refuse_unread, take_kind
from experiments.studies.protocol import Study
from experiments.testbed import Testbed


@dataclass(frozen=True)
class StudySettings:
    """lams: the sweep (>= 0, physical units; include 0); paper_lam: the regularized value
    the report compares with lambda = 0 (config keys ``lambdas``, ``paper_lambda``); hidden:
    neurons n_l; seeds: training seeds per lambda; inside: the training reference; outside:
    references that leave its range (first: the paper's r2); pgnn: network and optimizer
    settings shared by every model."""

    lams: tuple[float, ...] = (0.0, 1e-4, 1e-3, 1e-2, 1e-1, 1.0)
    paper_lam: float = 0.01
    hidden: int = 16
    seeds: int = 3
    inside: str = "r1"
    outside: tuple[str, ...] = ("r2",)
    pgnn: PGNNSettings = field(default_factory=PGNNSettings)
    aliases: ClassVar[dict[str, str]] = {FILE_KEYS[k]: k for k in ("lams", "paper_lam")}

    def __post_init__(self):
        if not self.lams or any(lam < 0 for lam in self.lams):
            raise UserError("lambdas: expected a non-empty list of numbers >= 0")
        if 0.0 not in self.lams or self.paper_lam not in self.lams:
            raise UserError(f"lambdas: must contain 0 and paper_lambda "
                            f"({self.paper_lam:g})")
        if not (isinstance(self.seeds, int) and self.seeds >= 1) or self.hidden < 1:
            raise UserError("seeds and hidden: expected integers >= 1")
        if self.inside in self.outside:
            raise UserError(f"outside: {self.inside!r} is the inside reference; an outside "
                            f"reference leaves the training range")


def load_study(path) -> tuple[ExperimentConfig, StudySettings]:
    """Read a study config and make ``clm-sim run``'s checks before any computation; errors
    name the file and the key. A config without a ``study:`` section is refused (it is an
    experiment for ``clm-sim run``)."""
    path = Path(path)
    data = take_kind(load_yaml(path), path, "extrapolation")
    has_study = "study" in data  # an empty 'study:' takes every default
    settings = data.pop("study", None)
    try:
        if has_study:  # before the build, whose checks assume a run on the records
            refuse_unread(data, "extrapolation", "study", ("data",))
        config = build(ExperimentConfig, data, "config")
        preflight(config)
        if not has_study:
            raise UserError("needs a 'study:' section (lambdas, seeds, ...); a plain experiment "
                            "runs with 'clm-sim run'")
        refuse_unread(data, "extrapolation", "study")
        study = build(StudySettings, settings, "study")
    except UserError as exc:
        raise in_file(path, exc) from None
    for key in (study.inside, *study.outside):
        if key not in config.references:
            raise UserError(f"{path}: study: reference {key!r} is not defined under 'references'")
    return config, study


def _variants(study: StudySettings):
    """(key, label, spec) of every trained PGNN variant, sequential first."""
    common = {"kind": "pgnn", "hidden": study.hidden, "seeds": study.seeds, "pgnn": study.pgnn}
    out = [(SEQUENTIAL, "sequential", FeedforwardSpec(training="sequential", **common))]
    for lam in sorted(study.lams):
        out.append((variant_key(lam), f"λ = {lam:g}",
                    FeedforwardSpec(training="simultaneous", lam=lam, **common)))
    return out


@dataclass(frozen=True)
class Scene:
    """What the figures draw beyond the result: the trained models, their replays, the LIP,
    the references, the true force and each model's two parts (a figure never predicts)."""

    config: ExperimentConfig
    lip: object
    refs: dict
    models: dict
    runs: dict
    truth: dict
    parts: dict


def compute(config: ExperimentConfig, study: StudySettings, *,
            progress=None) -> tuple[ExtrapolationResult, Scene]:
    """Train and replay every variant; the result and what its figures draw."""
    progress = progress or (lambda message: None)
    ts = config.ts
    tb = Testbed(config, progress=progress)
    train = tb.training_run()
    lip = tb.fit_lip(train)
    names = (study.inside, *study.outside)
    refs = {k: tb.reference(k) for k in names}

    def replay(model):
        return {k: tb.replay(model, k) for k in names}

    runs = {FEEDBACK: replay(None), LIP: replay(lip)}
    models: dict[str, list] = {}
    mae: dict[str, dict[str, list[float]]] = {
        k: {r: [run.mae] for r, run in v.items()} for k, v in runs.items()}
    for key, label, spec in _variants(study):
        models[key], mae[key] = [], {r: [] for r in refs}
        for s, model in enumerate(tb.fit_row(spec, train, lip)):
            replays = replay(model)
            for r, run in replays.items():
                mae[key][r].append(run.mae)
            if s == 0:
                runs[key] = replays
            models[key].append(model)
        progress(f"  {label}: MAE " + ", ".join(
            f"{r} {np.mean(v) * 1e6:.3f} µm" for r, v in mae[key].items()))

    truth = {}
    for k, r in refs.items():  # the simulator's own plant: the oracle a real machine lacks
        y, v, a = config.features.motion(r, ts)
        truth[k] = tb.machine.inverse_force(y, v, a)
    # Each model's two parts on each reference, predicted once: the summary and the figures
    # read them (a figure never predicts).
    parts = {key: {r: [m.predict_parts(y=ref, ts=ts) for m in ms] for r, ref in refs.items()}
             for key, ms in models.items()}
    summary = _summarize(config, study, lip, refs, models, mae, runs, truth, parts)
    return summary, Scene(config, lip, refs, models, runs, truth, parts)


def _figures(summary: ExtrapolationResult, folder: Path, scene: Scene) -> None:
    """The report's figures into ``folder``."""
    config, lip, refs, models = scene.config, scene.lip, scene.refs, scene.models
    runs, truth, parts = scene.runs, scene.truth, scene.parts
    ts = config.ts
    plots.save(figures.theta_figure(summary, models), folder / "theta_training.png")
    plots.save(figures.cost_figure(summary, models), folder / "cost_terms.png")
    inside = summary.ranges[summary.inside]
    for ref in summary.outside:
        beyond = inside.beyond(config.features, refs[ref], ts)
        split = ForceSplit(reference=ref, ts=ts, r=refs[ref],
                           lip_force=lip.predict(y=refs[ref], ts=ts), beyond=beyond,
                           parts={key: p[ref][0] for key, p in parts.items()},
                           truth=truth[ref])
        plots.save(figures.split_figure(summary, split), folder / f"split_{ref}.png")
    shown = [FEEDBACK, LIP, SEQUENTIAL, variant_key(0.0), variant_key(summary.paper_lam)]
    colors = {_label(k): c for k, c in figures.variant_colors(summary).items()}
    for ref in refs:
        replays = {_label(k): runs[k] for k in shown}
        plots.save(plots.tracking_figure(replays, ref, colors), folder / f"tracking_{ref}.png")
    plots.save(figures.mae_vs_lambda_figure(summary), folder / "mae_vs_lambda.png")


def _label(key: str) -> str:
    """A variant key as the figures name it (``lambda=0`` -> ``PGNN λ = 0``)."""
    return key if key in (FEEDBACK, LIP) else "PGNN " + variant_label(key)


def _seed_mean(seeds: list[BeyondRange], get) -> float | None:
    """The mean over seeds of one quantity ``get(b)`` (None where no sample leaves the range)."""
    values = [get(b) for b in seeds]
    return None if None in values else float(np.mean(values))


def _summarize(config, study, lip, refs, models, mae, runs, truth,
               predicted) -> ExtrapolationResult:
    ts = config.ts
    ranges = {r: TrainingRange.of(config.features, ref, ts) for r, ref in refs.items()}
    variants = {}
    for key, ms in models.items():
        parts = {}
        for r, ref in refs.items():
            beyond = ranges[study.inside].beyond(config.features, ref, ts)
            seeds = [BeyondRange.of(p, n, beyond, truth[r]) for p, n in predicted[key][r]]
            mean = functools.partial(_seed_mean, seeds)
            parts[r] = NetworkParts(
                network_max_abs_n=mean(lambda b: b.network_peak_n),
                network_rms_n=mean(lambda b: b.network_rms_n),
                network_max_abs_beyond_n=mean(lambda b: b.network_peak_beyond_n),
                network_max_abs_within_n=mean(lambda b: b.network_peak_within_n),
                fraction_beyond=float(beyond.mean()),
                # Model force minus the true plant force, rms over the samples beyond the
                # training range (N), mean over seeds.
                model_error_beyond_rms_n=mean(lambda b: b.error_beyond_rms_n))
        trained = Trained(
            theta_phy_per_seed=tuple(m.theta_ for m in ms),
            theta_phy={k: float(np.mean([m.theta_[k] for m in ms])) for k in THETA_NAMES},
            cost=Costs(data=float(np.mean([m.cost_.data for m in ms])),
                       deviation=float(np.mean([m.cost_.deviation for m in ms]))),
            iterations=tuple(len(m.history_) - 1 for m in ms), parts=parts)
        variants[key] = Variant(
            mae={r: Spread(float(np.mean(v)), float(np.std(v, ddof=1)) if len(v) > 1 else 0.0,
                           tuple(v)) for r, v in mae[key].items()},
            trained=trained)
    lip_beyond = {}
    for r, ref in refs.items():
        beyond = ranges[study.inside].beyond(config.features, ref, ts)
        if beyond.any():
            lip_beyond[r] = float(np.sqrt(np.mean(
                (lip.predict(y=ref, ts=ts) - truth[r])[beyond] ** 2)))
    for key in (FEEDBACK, LIP):
        variants[key] = Variant(
            mae={r: Spread(v[0], 0.0, tuple(v)) for r, v in mae[key].items()},
            lip_error_beyond_rms_n=lip_beyond if key == LIP else None)
    return ExtrapolationResult(
        lams=tuple(sorted(study.lams)), paper_lam=study.paper_lam, hidden=study.hidden,
        seeds=study.seeds, inside=study.inside, outside=tuple(study.outside),
        theta_lip=lip.theta_, lip_residual_rms_n=lip.residual_rms_, ranges=ranges,
        variants=variants)


def _um(x: float) -> str:
    return f"{x * 1e6:.3f} µm"


def _findings(s: ExtrapolationResult) -> list[str]:
    """Sentences with this run's numbers that name the mechanism."""
    v, lip = s.variants, s.theta_lip
    zero, paper = s.unregularized.trained, s.regularized.trained
    inside = s.inside

    def drift(var: Trained):
        return {k: (var.theta_phy[k] - lip[k]) / abs(lip[k]) if lip[k] else np.inf
                for k in THETA_NAMES}

    dz, dp = drift(zero), drift(paper)
    order = sorted(THETA_NAMES, key=lambda k: -abs(dz[k]))
    lines = []
    lines.append(
        "**Which parameters drift.** Without regularization (λ = 0) θ_phy moves away from θ_LIP: "
        + "; ".join(f"{k} {lip[k]:.4g} → {zero.theta_phy[k]:.4g} {THETA_UNITS[k]} "
                    f"({dz[k] * 100:+.0f} %)" for k in order[:3])
        + f" (mean over {s.seeds} seeds). With λ = {s.paper_lam:g} the largest relative "
        f"change is {max(abs(x) for x in dp.values()) * 100:.2f} % ({max(dp, key=lambda k: abs(dp[k]))})."
        " Only the sum of physics and network is constrained by the data, so without the penalty the "
        "network absorbs part of what the physical terms explained (and vice versa).")
    rz, rp = zero.parts, paper.parts
    mz, mp = s.unregularized.mae, s.regularized.mae
    ml, ms = v[LIP].mae, v[SEQUENTIAL].mae
    rng_in = s.ranges[inside]
    lines.append(
        f"**Inside the training range ({inside}).** The network force of λ = 0 peaks at "
        f"{rz[inside].network_max_abs_n:.2f} N (rms {rz[inside].network_rms_n:.2f} N), that "
        f"of λ = {s.paper_lam:g} at {rp[inside].network_max_abs_n:.2f} N (rms "
        f"{rp[inside].network_rms_n:.2f} N): with λ = 0 the network carries what the drifted "
        f"physical terms no longer do. MAE on {inside}: λ = 0 {_um(mz[inside].mean)}, "
        f"λ = {s.paper_lam:g} {_um(mp[inside].mean)}, sequential "
        f"{_um(ms[inside].mean)}, LIP {_um(ml[inside].mean)}.")
    for outside in s.outside:
        rng_out = s.ranges[outside]
        leaves = [name for name, key in (("position", "position_m"), ("velocity", "velocity_m_s"),
                                         ("acceleration", "acceleration_m_s2"))
                  if getattr(rng_out, key) > getattr(rng_in, key) * 1.01]
        text = (f"**{outside}.** It reaches |y| = {rng_out.position_m * 1e3:.0f} mm, |v| = "
                f"{rng_out.velocity_m_s:.3g} m/s, |a| = {rng_out.acceleration_m_s2:.3g} m/s² "
                f"against {rng_in.position_m * 1e3:.0f} mm, {rng_in.velocity_m_s:.3g} m/s, "
                f"{rng_in.acceleration_m_s2:.3g} m/s² on {inside}: it extrapolates in "
                f"{', '.join(leaves) if leaves else 'nothing'}")
        bz, bp = rz[outside].network_max_abs_beyond_n, rp[outside].network_max_abs_beyond_n
        if bz is not None:
            ez = rz[outside].model_error_beyond_rms_n
            ep = rp[outside].model_error_beyond_rms_n
            eq = v[SEQUENTIAL].trained.parts[outside].model_error_beyond_rms_n
            el = v[LIP].lip_error_beyond_rms_n[outside]
            text += (f" ({rz[outside].fraction_beyond * 100:.0f} % of its samples). There the "
                     f"network force reaches {bz:.2f} N for λ = 0 and {bp:.2f} N for "
                     f"λ = {s.paper_lam:g}, and the whole model misses the true plant force "
                     f"by {ez:.2f} N rms for λ = 0, {ep:.2f} N for λ = {s.paper_lam:g}, "
                     f"{eq:.2f} N sequential and {el:.2f} N for the LIP")
        ratio = mz[outside].mean / mp[outside].mean
        # Paired over seeds: seed s of every variant shares the training run and the draw.
        d = np.array(mz[outside].per_seed) - np.array(mp[outside].per_seed)
        diff, lo, hi = t_interval(d)
        verdict = ("λ = 0 loses more than the regularized PGNN" if ratio > 1.1 else
                   "λ = 0 does not lose more than the regularized PGNN" if ratio > 0.9 else
                   "λ = 0 even does better than the regularized PGNN")
        verdict += (f" (paired difference {diff * 1e6:+.3f} µm, 95 % t-interval "
                    + (f"[{lo * 1e6:+.3f}, {hi * 1e6:+.3f}] µm" if len(d) > 1 else "none")
                    + f" over {len(d)} seeds: the interval "
                    + ("excludes" if len(d) > 1 and (lo > 0 or hi < 0) else "contains") + " 0)")
        text += (f". MAE: λ = 0 {_um(mz[outside].mean)} ± {_um(mz[outside].std)}, "
                 f"λ = {s.paper_lam:g} {_um(mp[outside].mean)} ± "
                 f"{_um(mp[outside].std)}, sequential {_um(ms[outside].mean)}, LIP "
                 f"{_um(ml[outside].mean)}; ratio λ = 0 / λ = {s.paper_lam:g} "
                 f"{ratio:.2f}: {verdict} here.")
        lines.append(text)
    return lines


def _report(s: ExtrapolationResult, study: StudySettings) -> str:
    v = s.variants
    refs = list(s.references)
    lines = [f"# Extrapolation study: PGNN with n_l = {s.hidden}, λ swept over "
             f"{', '.join(f'{x:g}' for x in s.lams)}", "",
             f"One dithered training run on {s.inside}, one LIP (θ_LIP: " + ", ".join(
                 f"{k} {x:.4g} {THETA_UNITS[k]}" for k, x in s.theta_lip.items())
             + f"), {s.seeds} training seeds per variant; replays without dither on "
             f"{s.inside} (the training range) and {', '.join(s.outside)}.", "",
             "## Findings (generated from this run)", ""]
    lines += [f"- {x}" for x in _findings(s)] + [""]
    head = (["variant"] + [f"MAE {r} [µm]" for r in refs]
            + ["m [kg]", "fv [N·s/m]", "fc [N]", "fk [N/m]", "data term [N²]",
               "deviation term [N²]"])
    lines += ["## Table (mean ± std over seeds)", "", "| " + " | ".join(head) + " |",
              "|" + "---|" * len(head)]
    for key, var in v.items():
        cells = [key] + [f"{var.mae[r].mean * 1e6:.3f} ± {var.mae[r].std * 1e6:.3f}"
                         for r in refs]
        t = var.trained
        cells += [f"{t.theta_phy[k]:.4g}" for k in THETA_NAMES] if t else ["–"] * 4
        cells += [f"{t.cost.data:.4g}", f"{t.cost.deviation:.3g}"] if t else ["–"] * 2
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", "## Figures", "",
              "θ_phy over the LM iterations, relative to θ_LIP (seed 0):", "",
              "![theta](figures/theta_training.png)", "",
              "Data-fit term and parameter-deviation term over the iterations (seed 0):", "",
              "![costs](figures/cost_terms.png)", ""]
    for r in s.outside:
        lines += [f"Feedforward on {r} split into the physical part θ_phy·T (minus the LIP force) "
                  f"and the network part (seed 0; shaded: samples outside the training range):",
                  "", f"![split {r}](figures/split_{r}.png)", ""]
    lines += ["Tracking errors per variant (seed 0):", ""]
    lines += [f"![tracking {r}](figures/tracking_{r}.png)\n" for r in refs]
    lines += ["MAE against λ (mean ± std over seeds; λ = 0 drawn at the left edge):", "",
              "![mae](figures/mae_vs_lambda.png)", ""]
    return "\n".join(lines)


STUDY = Study(
    kind="extrapolation", section="study", what="a clm-sim study", settings=StudySettings,
    load=load_study, compute=compute, result=ExtrapolationResult, result_file="study.json",
    report=_report, figures=_figures,
    resolved=lambda config, study: {**resolved(config), "study": to_plain(study)})
