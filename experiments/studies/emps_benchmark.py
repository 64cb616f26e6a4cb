"""The EMPS benchmark on the field's protocol: the product's physical models beside the published.

Protocol (nonlinearbenchmark.org, the ``nonlinear_benchmarks`` EMPS loader): train on
``DATA_EMPS.mat``, test on ``DATA_EMPS_PULSES.mat``; input ``u = gtau*vir`` (N), output ``qm``
(m); a model may use the test input and the first 20 test output samples (its initial state),
nothing else of the test record; score: RMSE (mm) of the open-loop simulated position over the
remaining samples. Every row is simulated by the same code (``clm_sim.open_loop``).

Rows, each made from the training record only (or from nothing: the published model):

* ``published``: Janot et al.'s IDIM-LS model as published (``benchmark.published_model``);
* ``published procedure``: the same procedure rerun by ``clm-sim identify`` with its options;
* ``product LIP`` and ``product LIP + offset``: ``clm-sim identify`` with its defaults, and with
  an offset column (one setting apart);
* ``diagnosis-extended``: the published model diagnosed on the whole training record (its
  reported gain on the record's final quarter is in-sample and not used), extended with what
  was named;
* ``published, output-error`` and ``extended, output-error``: those two models' parameters
  refined on the training record's simulation error (``experiments.output_error``; the two
  rows differ in the structure only).

Selection without test data: the training record is cut in time (``estimation_fraction``);
every candidate that is a measurement is made again, by the same procedure, from the first part
alone and ranked by its open-loop RMSE on the rest (initial state from that part's first
``init_samples``); the chosen row's test score is that of its fit on the whole training record.
Rule B reads the split from both ends (also made on the last part, scored on the first) and
ranks by the mean of the two held-out RMSEs. Rule C leaves one cycle of the training record's
repeated program out at a time and names the simplest candidate within one standard error of
the best mean (:mod:`experiments.studies.emps_cycles`).

Beside them: each row's closed-loop twin on both records (the published controller on the
reference, with ``known_input`` as a known external input), and why the diagnosis-extended model
drifts on the test record (:mod:`experiments.studies.emps_drift`).

``clm-sim study experiments/configs/emps_benchmark.yaml`` writes ``benchmark.json``,
``report.md`` (the page ``docs/results/emps_benchmark.md``) and ``figures/``.
"""

from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import dataclass, field
from pathlib import Path

from clm_sim.errors import UserError
from clm_sim.open_loop import MIN_SCORED_SAMPLES
from clm_sim.outdir import atomic_folder, check_output_folder
from clm_sim.plant import THETA_NAMES, Plant
from clm_sim.record import Run, load_record
from clm_sim.schema import build, load_yaml
from controllers.idim import IDIMProtocol
from experiments.diagnosis.model import SimulationModel, load_model
from experiments.simulation import Simulation, Twin, simulate_record, twin_record
from experiments.studies.emps_cycles import (CycleScores, cycle_edges, fitted_parameters,
                                             left_out, one_se_choice)
from experiments.studies.emps_drift import Drift, explain_drift, plot_drift
from experiments.studies.emps_plateaus import cycle_friction, plateaus
from experiments.studies.kinds import take_kind


@dataclass(frozen=True)
class Baseline:
    """A published score on the same protocol: ``name``, test RMSE (mm), ``source``."""

    name: str
    test_rmse_mm: float
    source: str = ""


@dataclass(frozen=True)
class BenchmarkSettings:
    """The ``benchmark:`` section: the records (paths relative to the current folder), how their
    columns map (``columns``, ``scale`` as ``clm-sim --columns/--scale``), the initialization
    window, the published model file and procedure, and the published baselines."""

    training: str
    test: str
    columns: dict[str, str] = field(default_factory=dict)
    scale: dict[str, str | float] = field(default_factory=dict)
    init_samples: int = 20
    published_model: str = "experiments/configs/emps_model.yaml"
    published_procedure: IDIMProtocol = field(default_factory=IDIMProtocol)
    baselines: tuple[Baseline, ...] = ()
    max_nfev: int = 400
    estimation_fraction: float = 2 / 3  # of the training record; the rest is held out
    # The test record's column of a known external input (in the input's unit, scaled like
    # ``u``), given to the closed-loop twin; "" for none.
    known_input: str = ""
    # Rule C: the training record's repetitions of its program, each left out once (0: no rule C).
    cycles: int = 0


@dataclass(frozen=True)
class Row:
    """One model: how it was made, from which data, its plant, and its scores."""

    name: str
    made_from: str
    plant: Plant
    cpu_s: float
    train: Simulation
    test: Simulation
    force_rms_test_n: float
    force_mean_test_n: float
    note: str = ""
    measured: bool = True  # False: an optimizer's end point that a second start does not repeat
    held_out: Simulation | None = None  # remade on the estimation part, on the held-out part
    held_out_plant: Plant | None = None  # the plant remade on the estimation part
    held_out_note: str = ""  # the note of the fit on the estimation part
    held_out_back: Simulation | None = None  # remade on the last part, on the first third
    twin_train: Twin | None = None  # the published controller around the row's plant
    twin_test: Twin | None = None
    cycles: CycleScores | None = None  # rule C: made without each cycle, simulated on it

    def to_json(self) -> dict:
        return {"name": self.name, "made_from": self.made_from, "note": self.note,
                "measured": self.measured,
                "cpu_s": self.cpu_s, "test_rmse_m": self.test.score.rmse,
                "train_rmse_m": self.train.score.rmse,
                "held_out_rmse_m": None if self.held_out is None else self.held_out.score.rmse,
                "held_out_parameters": None if self.held_out_plant is None else {
                    **self.held_out_plant.theta(), "offset_n": _offset(self.held_out_plant),
                    "effects": [e.as_config() for e in self.held_out_plant.effects]},
                "held_out_note": self.held_out_note,
                "held_out_backward_rmse_m": None if self.held_out_back is None else
                self.held_out_back.score.rmse,
                "left_one_cycle_out_rmse_m": None if self.cycles is None else
                list(self.cycles.rmse_m),
                "fitted_parameters": fitted_parameters(self.plant),
                **{f"twin_{k}": None if t is None else t.to_json() for k, t in
                   (("train", self.twin_train), ("test", self.twin_test))},
                "test_fit_percent":
                self.test.score.fit_percent, "force_residual_rms_test_n": self.force_rms_test_n,
                "force_residual_mean_test_n": self.force_mean_test_n,
                "parameters": {**self.plant.theta(), "offset_n": _offset(self.plant),
                               "effects": [e.as_config() for e in self.plant.effects]}}


def _offset(plant: Plant) -> float:
    return float(sum(e.force_n for e in plant.effects if e.type == "force_offset"))


def load_benchmark(path) -> tuple[str, BenchmarkSettings]:
    data = take_kind(load_yaml(path), path, "emps_benchmark")
    unknown = set(data) - {"name", "benchmark"}
    if unknown or "benchmark" not in data:
        raise UserError(f"{path}: a benchmark config has 'name' and 'benchmark:' only"
                        + (f" (unknown: {', '.join(sorted(unknown))})" if unknown else ""))
    try:
        settings = build(BenchmarkSettings, data["benchmark"], "benchmark")
    except UserError as exc:
        raise UserError(f"{path}: {exc}") from None
    if not 0 < settings.estimation_fraction < 1:
        raise UserError(f"{path}: benchmark.estimation_fraction: expected a number between 0 "
                        f"and 1 (the first part of the training record), got "
                        f"{settings.estimation_fraction}")
    if settings.cycles == 1 or settings.cycles < 0:
        raise UserError(f"{path}: benchmark.cycles: expected 0 (no rule C) or at least 2 "
                        f"repetitions of the training record's program, got {settings.cycles}")
    return str(data.get("name", Path(path).stem)), settings


def _force_residual(plant: Plant, run: Run) -> tuple[float, float]:
    """RMS and mean (N) of the diagnosis's force residual (measured force minus the model's
    inverse dynamics, low-passed) of ``plant`` on ``run``: the mean is the constant force the
    model misses, which an open-loop simulation integrates twice."""
    from experiments.diagnosis.residual import DiagnosisSettings, Residual

    res = Residual(run, plant, DiagnosisSettings())
    return float(res.rms()), float(res.z.mean())


@dataclass(frozen=True)
class Made:
    """A candidate model made from one record: its plant, the CPU seconds it took, the note of
    its fit, and whether it is a measurement (``False``: an optimizer's stop that a second start
    does not repeat)."""

    name: str
    made_from: str
    plant: Plant
    cpu_s: float
    note: str = ""
    measured: bool = True
    second: Plant | None = None  # an output-error fit's second start's end


def split(run: Run, fraction: float, init_samples: int) -> tuple[Run, Run]:
    """``run`` cut in time: the first ``fraction`` of its samples (estimation) and the rest
    (held out, simulated from its own first ``init_samples`` outputs like a test record)."""
    cut = int(round(fraction * len(run)))
    need = init_samples + MIN_SCORED_SAMPLES  # each part: its initialization, then a scored window
    if 2 * need > len(run):  # no fraction can give both parts their window
        raise UserError(f"benchmark.init_samples: {init_samples} initialization samples leave "
                        f"no split of the {len(run)}-sample training record in which each "
                        f"part has {MIN_SCORED_SAMPLES} more to score; at most "
                        f"{len(run) // 2 - MIN_SCORED_SAMPLES}")
    if not (need <= cut <= len(run) - need):
        raise UserError(f"benchmark.estimation_fraction: {fraction} leaves {cut} and "
                        f"{len(run) - cut} samples; each part needs the {init_samples} "
                        f"initialization samples and {MIN_SCORED_SAMPLES} more to score")
    return run.slice(0, cut), run.slice(cut)


def twin_record_of(settings: BenchmarkSettings, path) -> Run:
    """The record at ``path`` as the closed-loop twin reads it: ``settings.known_input`` (a
    column in the input's unit, e.g. the pulses in V) as ``u_ff``, scaled like ``u``; the twin
    takes its reference and this input, never the measured output."""
    if not settings.known_input:
        return load_record(path, columns=settings.columns, scale=settings.scale)
    return load_record(path, columns={**settings.columns, "u_ff": settings.known_input},
                       scale={**settings.scale, "u_ff": settings.scale.get("u", 1.0)})


def make_models(record: Run, published, settings: BenchmarkSettings, *, second_start=True,
                skip=(), progress=print) -> list[Made]:
    """Every candidate of the table made from ``record`` alone (the published model: from
    nothing), in the table's order. ``second_start``: repeat each output-error fit from the
    LIP + offset's parameters to tell a measurement from an optimizer's stop; names in ``skip``
    are not made (``None`` in their place)."""
    from controllers.idim import fit as idim_fit
    from experiments.diagnosis import DiagnosisSettings, diagnose
    from experiments.output_error import refine

    n0 = settings.init_samples
    made: list[Made | None] = []

    def add(m: Made) -> Made:
        made.append(m)
        return m

    add(Made("published model", "nothing (the published parameters)", published.plant, 0.0))

    def lip_row(name, protocol, made_from):
        cpu = time.process_time()
        f = idim_fit(y=record.y, u=record.u, ts=record.ts, protocol=protocol)
        plant = dataclasses.replace(published.plant, **f.model.theta_, effects=f.model.effects_)
        return add(Made(name, made_from, plant, time.process_time() - cpu))

    lip_row("published procedure (identify options)",
            settings.published_procedure, "training record (IDIM-LS)")
    lip_row("product LIP (identify)", IDIMProtocol(), "training record (LIP)")
    lip = lip_row("product LIP + offset (identify --offset)", IDIMProtocol(offset=True),
                  "training record (LIP)")

    def refined(name, plant):
        """Output-error fit from ``plant``, and (``second_start``) again from the LIP + offset's
        parameters in the same structure: the note says whether the two ends agree."""
        if name in skip:
            return made.append(None)
        cpu = time.process_time()
        fit = refine(plant, record, init_samples=n0, max_nfev=settings.max_nfev)
        cpu = time.process_time() - cpu
        if not second_start:
            return add(Made(name, "training record (simulation error)", fit.plant, cpu,
                            _stop(fit)))
        other = refine(_restart(plant, lip.plant), record, init_samples=n0,
                       max_nfev=settings.max_nfev)
        spread = max(abs(other.values[k] - v) / max(abs(v), 1e-9) for k, v in fit.values.items())
        # A measurement only where both starts converge to one point: training RMSE within 1 %
        # and every parameter within AGREE (decided on the training record alone).
        agree = (fit.converged and other.converged and spread <= AGREE
                 and abs(other.rmse_m / fit.rmse_m - 1) <= 0.01)
        note = (f"{_stop(fit)}. Second start (the LIP + offset's parameters): {_stop(other)}; "
                f"the two ends differ by up to {100 * spread:.2g} % in a parameter: "
                + ("one end point, a measurement" if agree else
                   "two end points, so the row is the first start's stop, not a measurement"))
        m = add(Made(name, "training record (simulation error)", fit.plant, cpu, note, agree,
                     other.plant))
        progress(f"{name}: second start ends at {other.rmse_m * 1e3:.3f} mm training RMSE")
        return m

    refined("published, output-error", published.plant)

    cpu = time.process_time()
    # Causes selected and fitted on the whole record given; the gain the diagnosis reports is
    # then measured on its own final quarter (not out of sample; the table does not use it).
    cut = int(round(0.75 * len(record)))
    diag = diagnose(record, published, validation=record.slice(cut),
                    settings=DiagnosisSettings())
    add(Made("diagnosis-extended", "training record (force residual)", diag.extended,
             time.process_time() - cpu, "; ".join(f.effect for f in diag.findings)))
    refined("diagnosis-extended, output-error", diag.extended)
    return made


def run_benchmark(settings: BenchmarkSettings, progress=print) -> tuple[list[Row], Drift]:
    """Every row made from the whole training record and simulated on both records (open loop,
    and as the closed-loop twin under the published model's controller), and made again from the
    training record's estimation part and simulated on its held-out part (paths relative to the
    current folder); rows that are not measurements are not remade. With them, why the
    diagnosis-extended model drifts (:func:`experiments.studies.emps_drift.explain_drift`)."""

    def path(key):
        p = Path(getattr(settings, key))
        if not p.exists():
            raise UserError(f"benchmark.{key}: file not found: {p} (paths are relative to the "
                            f"current folder {Path.cwd()})")
        return p

    train, test = (load_record(path(k), columns=settings.columns, scale=settings.scale)
                   for k in ("training", "test"))
    published = load_model(path("published_model"))
    twin_test = twin_record_of(settings, path("test"))
    n0 = settings.init_samples
    estimation, held_out = split(train, settings.estimation_fraction, n0)
    # Backward: the same split read from the other end (estimation on the last part).
    held_back, estimation_back = split(train, 1 - settings.estimation_fraction, n0)
    # Rule C's cycles are found in the record before any model is made (minutes of fits).
    edges = cycle_edges(train.r, settings.cycles) if settings.cycles else ()

    def sim(plant, run, source=None):
        return simulate_record(SimulationModel(plant, None, "model", train.ts), run,
                               init_samples=n0, source=source)

    def twin(plant, run, source):
        if published.controller is None:
            return None
        return twin_record(SimulationModel(plant, published.controller, "model", train.ts),
                           run, source=source)

    progress(f"whole training record ({len(train)} samples):")
    full = make_models(train, published, settings, progress=progress)
    progress(f"estimation part (the first {len(estimation)} samples), for the held-out part "
             f"(the last {len(held_out)}):")
    part = make_models(estimation, published, settings, second_start=False,
                       skip={m.name for m in full if not m.measured}, progress=progress)
    progress(f"estimation part read backward (the last {len(estimation_back)} samples), for "
             f"the first {len(held_back)}:")
    back = make_models(estimation_back, published, settings, second_start=False,
                       skip={m.name for m in full if not m.measured}, progress=progress)
    folds = []  # rule C: (the left-out cycle, the candidates made without it)
    for k in range(settings.cycles):
        rest, cycle = left_out(train, edges, k)
        progress(f"every cycle but cycle {k + 1} of {settings.cycles} ({len(rest)} samples), "
                 f"for that cycle ({len(cycle)}):")
        folds.append((cycle, make_models(rest, published, settings, second_start=False,
                                         skip={m.name for m in full if not m.measured},
                                         progress=progress)))
    rows = []
    for i, (m, e, b) in enumerate(zip(full, part, back)):
        cyc = None if not folds or any(f[i] is None for _, f in folds) else CycleScores(
            tuple(sim(f[i].plant, cycle, f"cycle {k + 1}").score.rmse
                  for k, (cycle, f) in enumerate(folds)), fitted_parameters(m.plant),
            tuple(_params(f[i].plant) + (f" ({f[i].note})" if f[i].note else "")
                  for _, f in folds))
        note = m.note if m.second is None else (
            f"{m.note}; the second start's test RMSE "
            f"{sim(m.second, test).score.rmse * 1e3:.3f} mm")
        r = Row(m.name, m.made_from, m.plant, m.cpu_s, sim(m.plant, train, settings.training),
                sim(m.plant, test, settings.test), *_force_residual(m.plant, test), note,
                m.measured, None if e is None else sim(e.plant, held_out, "held-out part"),
                None if e is None else e.plant, "" if e is None else e.note,
                None if b is None else sim(b.plant, held_back, "first part"),
                twin(m.plant, train, settings.training), twin(m.plant, twin_test, settings.test),
                cyc)
        progress(f"{m.name}: test RMSE {r.test.score.rmse * 1e3:.3f} mm, training "
                 f"{r.train.score.rmse * 1e3:.3f} mm, held-out "
                 + ("not refitted" if e is None else f"{r.held_out.score.rmse * 1e3:.3f} mm")
                 + f" ({m.cpu_s:.1f} s CPU)")
        rows.append(r)
    progress("why the extended model drifts: its terms taken apart")
    drift = explain_drift(train, test, published.plant, sim, estimation=estimation,
                          held_out=held_out)
    steady = cycle_friction(plateaus(train, edges or (0, len(train))))
    return rows, dataclasses.replace(drift, steady=tuple(steady))


def _restart(plant: Plant, start: Plant) -> Plant:
    """``plant``'s structure (offsets merged) with ``start``'s theta and constant force."""
    from experiments.output_error import merge_offsets

    p = merge_offsets(plant)
    effects = tuple(dataclasses.replace(e, force_n=_offset(start)) if e.type == "force_offset"
                    else e for e in p.effects)
    return dataclasses.replace(p, **start.theta(), effects=effects)


AGREE = 0.05  # largest relative parameter difference between two starts' ends of one optimum


def _stop(fit) -> str:
    return (f"{'converged' if fit.converged else 'stopped'} after {fit.nfev} evaluations "
            f"({fit.message.rstrip('.')}); training RMSE {fit.rmse_start_m * 1e3:.3f} -> "
            f"{fit.rmse_m * 1e3:.3f} mm")


def _params(p: Plant) -> str:
    extra = [e.type for e in p.effects if e.type != "force_offset"]
    return (f"M {p.mass:.2f}, Fv {p.viscous:.1f}, Fc {p.coulomb:.2f}, k {p.stiffness:.3g}, "
            f"OF {_offset(p):+.2f}" + (f"; {', '.join(extra)}" if extra else ""))


def _span(y, u, t) -> str:
    """The stroke, the peak speed (from sample differences) and the peak force of a measured
    position (m) and input (N)."""
    import numpy as np

    v = np.abs(np.diff(y)) / (t[1] - t[0])
    return (f"positions {y.min():.3f} to {y.max():.3f} m, peak speed {v.max():.3f} m/s, peak "
            f"force {np.abs(u).max():.0f} N")


def _rule_c(pub: Row, candidates: list[Row], settings: BenchmarkSettings) -> list[str]:
    """Rule C's verdict and its table: each candidate made without one cycle of the training
    record, simulated on that cycle; the simplest within one standard error of the best mean."""
    scored = {r.name: r.cycles for r in candidates if r.cycles is not None}
    if not scored:
        return []
    by_name = {r.name: r for r in candidates}
    pick = by_name[one_se_choice(scored)]
    best = min(scored, key=lambda k: scored[k].mean)
    bar = scored[best].mean + scored[best].se
    mm, p_mm = pick.test.score.rmse * 1e3, pub.test.score.rmse * 1e3
    k = len(pick.cycles.rmse_m)
    head = "| model | fitted parameters | " + " | ".join(
        f"cycle {j + 1} (mm)" for j in range(k)) + " | mean ± se (mm) | within one se |"
    table = [head, "|---" * (k + 4) + "|"]
    for r in [pub, *candidates]:
        c = r.cycles
        if c is None:
            continue
        table.append(f"| {r.name} | {c.parameters} | "
                     + " | ".join(f"{x * 1e3:.2f}" for x in c.rmse_m)
                     + f" | {c.mean * 1e3:.2f} ± {c.se * 1e3:.2f} | "
                     + ("(not a candidate)" if r is pub else
                        "yes" if c.mean <= bar else "no") + " |")
    return [
        f"Left one cycle out (rule C, written down before its first result: the training "
        f"record's program repeats {k} times, cut at the reference's reversals at the low end; "
        f"every candidate made on the other cycles joined and simulated on the left-out one; "
        f"the candidate with the fewest fitted parameters whose mean RMSE is within one "
        f"standard error of the lowest mean), the choice is **{pick.name}**: "
        f"{pick.cycles.mean * 1e3:.2f} ± {pick.cycles.se * 1e3:.2f} mm over the cycles "
        f"(lowest mean: {best}, {scored[best].mean * 1e3:.2f} ± {scored[best].se * 1e3:.2f} "
        f"mm), {pick.cycles.parameters} fitted parameters; {mm:.2f} mm on test, "
        f"{'better' if mm < p_mm else 'worse'} than the published model by "
        f"{abs(100 * (mm / p_mm - 1)):.1f} % ({mm - p_mm:+.3f} mm).", "", *table, "",
        *([] if not any(r.cycles.remade for r in candidates if r.cycles) else [
            "Made without each cycle (rule C's folds):", "",
            *(f"- {r.name}, without cycle {j + 1}: {d}" for r in candidates if r.cycles
              for j, d in enumerate(r.cycles.remade)), ""])]


def _twin_table(rows: list[Row]) -> list[str]:
    """The closed-loop twin of each row on both records: position (µm) and input (N) RMSE."""
    cell = lambda t, w: "–" if t is None else (  # noqa: E731
        f"{t.position.rmse * 1e6:.1f}" if w == "y" else f"{t.input.rmse:.2f}")
    return ["| model | twin position RMSE, training (µm) | twin input RMSE, training (N) | "
            "twin position RMSE, test (µm) | twin input RMSE, test (N) |",
            "|---|---|---|---|---|"] + [
        f"| {r.name} | {cell(r.twin_train, 'y')} | {cell(r.twin_train, 'u')} | "
        f"{cell(r.twin_test, 'y')} | {cell(r.twin_test, 'u')} |" for r in rows]


def to_markdown(name: str, rows: list[Row], settings: BenchmarkSettings, command: str,
                drift: Drift | None = None) -> str:
    pub = rows[0]
    product = rows[1:]
    candidates = [r for r in product if r.measured and r.held_out is not None]
    by_held = min(candidates, key=lambda r: r.held_out.score.rmse)
    both = lambda r: (r.held_out.score.rmse + r.held_out_back.score.rmse) / 2  # noqa: E731
    by_both = min((r for r in candidates if r.held_out_back is not None), key=both,
                  default=None)
    hb = lambda r: "–" if r.held_out_back is None else (  # noqa: E731
        f"{r.held_out_back.score.rmse * 1e3:.2f}")
    by_train = min((r for r in product if r.measured), key=lambda r: r.train.score.rmse)
    by_test = min(product, key=lambda r: r.test.score.rmse)
    mm = lambda r: r.test.score.rmse * 1e3  # noqa: E731
    ho = lambda r: "–" if r.held_out is None else f"{r.held_out.score.rmse * 1e3:.2f}"  # noqa
    lines = ["| model | made from | test RMSE (mm) | training RMSE (mm) | held-out RMSE (mm) | "
             "held-out backward (mm) | "
             "test fit (%) | force residual on test, RMS (N) | its mean (N) | "
             "parameters (kg, N·s/m, N, N/m, N) | CPU (s) |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]

    def fit(r) -> str:  # undefined (None) where the test record does not move
        return "–" if r.test.score.fit_percent is None else f"{r.test.score.fit_percent:.1f}"

    for r in rows:
        lines.append(f"| {r.name}{'' if r.measured else ' †'} | {r.made_from} | {mm(r):.2f} | "
                     f"{r.train.score.rmse * 1e3:.2f} | {ho(r)} | {hb(r)} | {fit(r)} | "
                     f"{r.force_rms_test_n:.3f} | {r.force_mean_test_n:+.3f} | "
                     f"{_params(r.plant)} | {r.cpu_s:.1f} |")
    for b in settings.baselines:
        lines.append(f"| {b.name} (black box, published) | {b.source} | {b.test_rmse_mm:.1f} | "
                     f"– | – | – | – | – | – | – | – |")
    rel = lambda r: 100 * (mm(r) / mm(pub) - 1)  # noqa: E731
    n_train = len(pub.train.t)
    n_held = len(pub.held_out.t)
    n_est = n_train - n_held
    ranking = lambda key, rs: ", ".join(  # noqa: E731
        f"{r.name} {key(r) * 1e3:.2f}" for r in sorted(rs, key=key))
    verdict = [
        "† an optimizer's stop that a second start does not repeat: not a measurement, not "
        "a candidate below, and not remade on the estimation part (held-out: –).", "",
        f"The published model simulates the test record to {mm(pub):.2f} mm. **Chosen by the "
        f"training record alone** (every candidate remade on its first {n_train - n_held} "
        f"samples, the same procedure, and ranked by the open-loop RMSE on its last {n_held} "
        f"samples, initial state from their first {settings.init_samples}), the product's best "
        f"physical model is **{by_held.name}**: held-out {ho(by_held)} mm; fitted on the whole "
        f"training record, {mm(by_held):.2f} mm on test, "
        f"{'better' if rel(by_held) < 0 else 'worse'} than the published model by "
        f"{abs(rel(by_held)):.1f} % ({mm(by_held) - mm(pub):+.3f} mm).",
        f"Held-out ranking (mm): {ranking(lambda r: r.held_out.score.rmse, candidates)}; the "
        f"published model {ho(pub)}. The two parts: estimation "
        f"{_span(pub.train.y_measured[:n_est], pub.train.u[:n_est], pub.train.t)}, held out "
        f"{_span(pub.held_out.y_measured, pub.held_out.u, pub.train.t)}; the test record "
        f"{_span(pub.test.y_measured, pub.test.u, pub.test.t)}.",
        *([] if by_both is None else [
            f"Read in both directions (rule B, written down before its first result: every "
            f"candidate also remade on the last {n_train - n_held} samples and simulated on the "
            f"first {n_held}; ranked by the mean of the two held-out "
            f"RMSEs), the choice is **{by_both.name}**: {both(by_both) * 1e3:.2f} mm mean "
            f"held-out, {mm(by_both):.2f} mm on test, "
            f"{'better' if rel(by_both) < 0 else 'worse'} than the published model by "
            f"{abs(rel(by_both)):.1f} % ({mm(by_both) - mm(pub):+.3f} mm). Ranking (mm): "
            f"{ranking(both, [r for r in candidates if r.held_out_back is not None])}; the "
            f"published model {both(pub) * 1e3 if pub.held_out_back else float('nan'):.2f}."]),
        *_rule_c(pub, candidates, settings),
        f"For contrast, the in-sample rule (lowest training RMSE of the fit on the whole "
        f"training record) would pick **{by_train.name}**: {mm(by_train):.2f} mm on test. "
        f"In-sample ranking (mm): "
        f"{ranking(lambda r: r.train.score.rmse, [r for r in product if r.measured])}.",
        f"The product row with the lowest test RMSE is **{by_test.name}**: {mm(by_test):.2f} mm, "
        f"{abs(rel(by_test)):.0f} % {'below' if rel(by_test) < 0 else 'above'} the published "
        f"model; " + ("it is also the held-out choice." if by_test is by_held else
                      "the held-out rule would not have chosen it, so this is a measurement "
                      "on the test record, not a model selected without it.")]
    notes = [f"- {r.name}: {r.note}" for r in rows if r.note]
    remade = [f"- {r.name}: {_params(r.held_out_plant)}"
              + (f" ({r.held_out_note})" if r.held_out_note else "")
              for r in rows[1:] if r.held_out_plant is not None]
    return "\n".join([f"<!-- generated by: {command} -->", "", *lines, "", *verdict, "",
                      "Fits and findings:", "", *notes, "",
                      f"Remade on the estimation part (the first {n_train - n_held} samples of "
                      f"the training record) for the held-out column:", "", *remade, "",
                      "Closed-loop twin (the published controller around each row's plant, "
                      "on the record's reference qg"
                      + (f" and the known input {settings.known_input}"
                         if settings.known_input else "") + "; from rest, nothing taken from "
                      "the measured output; scored over all samples):", "", *_twin_table(rows),
                      "", *([] if drift is None else [
                          "Why the diagnosis-extended model drifts (its terms taken apart; "
                          "test columns after the fact):", "",
                          *drift.to_markdown(pub.test.score.rmse), ""])])


def main(config_path, out=None, *, quiet: bool = False) -> int:
    """``clm-sim study CONFIG`` for a config with a ``benchmark:`` section."""
    from experiments import plots
    from experiments.simulation import plot_simulation

    name, settings = load_benchmark(config_path)
    out = Path(out) if out else Path("results") / Path(config_path).stem
    # Before the work (minutes of fits on EMPS): what the result folder will refuse, the
    # benchmark's inputs among it.
    inputs = (config_path, settings.training, settings.test, settings.published_model)
    check_output_folder(out, what="a benchmark", inputs=inputs)
    progress = (lambda s: None) if quiet else (lambda s: print(s, flush=True))
    try:
        rows, drift = run_benchmark(settings, progress)
    except UserError as exc:  # a setting the records cannot meet: name the config too
        text = str(exc)
        raise UserError(text if text.startswith(str(config_path)) else
                        f"{config_path}: {text}") from None
    command = f"clm-sim study {config_path}"
    table = to_markdown(name, rows, settings, command, drift)
    with atomic_folder(out, what="a benchmark", inputs=inputs) as tmp:
        (tmp / "benchmark.json").write_text(json.dumps(
            {"name": name, "command": command, "rows": [r.to_json() for r in rows],
             "baselines": [dataclasses.asdict(b) for b in settings.baselines],
             "init_samples": settings.init_samples,
             "estimation_fraction": settings.estimation_fraction, "cycles": settings.cycles,
             "drift": drift.to_json()}, indent=1))
        (tmp / "table.md").write_text(table)
        for i, r in enumerate(rows):
            axes = plot_simulation(r.test)
            plots.save(axes[0].figure, tmp / "figures" / f"test_{i}.png")
        if drift.traces:
            plots.save(plot_drift(drift).figure, tmp / "figures" / "drift.png")
    print(table, end="")
    return 0
