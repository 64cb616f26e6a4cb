"""The EMPS benchmark on the field's protocol: physical models fitted by simulation error, one
chosen by the training record's own cycles.

Protocol (nonlinearbenchmark.org, the ``nonlinear_benchmarks`` EMPS loader): train on
``DATA_EMPS.mat``, test on ``DATA_EMPS_PULSES.mat``; input ``u = gtau*vir`` (N), output ``qm``
(m); a model may use the test input and the first 20 test output samples (its initial state: a
parabola through them), nothing else of the test record; score: RMSE (mm) of the open-loop
simulated position over the remaining samples (``clm_sim.open_loop``).

Reference rows (not candidates): the published model, the published procedure (IDIM-LS) rerun,
the diagnosis-extended model fitted by force residual. Candidates (``benchmark.candidates``):
structures fitted by simulation error from several starts (:mod:`experiments.records.output_error`).

Selection (``benchmark.selection``, written in the config before its first result): every
candidate made again by its whole procedure on all cycles of the training record's program but
one and simulated open loop on the left-out one; the candidate with the lowest mean left-out
RMSE among those whose whole-record fit is a measurement. No fit on a fold starts from or keeps
a number identified on the whole record; the leak of a rule that does is sized
(:func:`leak`). Beside it: the band of test scores over every end point, each candidate's
sensitivity of the test score to its parameters (:func:`sensitivity`), the initial-state
method's effect, and why the force-residual extension drifts
(:mod:`experiments.studies.emps.drift`).

``clm-sim study experiments/configs/emps_benchmark.yaml`` writes ``benchmark.json``,
``report.md``, ``models/`` (one model file per row) and ``figures/``.
"""

from __future__ import annotations

import dataclasses
import re
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from clm_sim.errors import UserError
from clm_sim.open_loop import MIN_SCORED_SAMPLES, InitialState, initial_state, simulate_input
from clm_sim.plant import Plant
from clm_sim.records.read import load_record
from clm_sim.run import Run
from controllers.idim import IDIMProtocol
from experiments.records import output_error as oe
from experiments.model_files import SimulationModel, load_model
from experiments.records.simulation import simulate_record
from experiments.studies.emps.cycles import cycle_edges, left_out
from experiments.studies.emps.drift import Drift, explain_drift
from experiments.studies.emps.plateaus import cycle_friction, plateaus
from experiments.studies.emps.settings import BenchmarkSettings, Candidate
from experiments.processes.workers import map_in_order

def split(run: Run, fraction: float, init_samples: int) -> tuple[Run, Run]:
    """``run`` cut in time: the first ``fraction`` of its samples and the rest (simulated from
    its own first ``init_samples`` outputs like a test record)."""
    cut = int(round(fraction * len(run)))
    need = init_samples + MIN_SCORED_SAMPLES
    if not (need <= cut <= len(run) - need):
        raise UserError(f"split: {fraction} leaves {cut} and {len(run) - cut} samples; each "
                        f"part needs the {init_samples} initialization samples and "
                        f"{MIN_SCORED_SAMPLES} more to score")
    return run.slice(0, cut), run.slice(cut)


# ----------------------------------------------------------------------------- making models

def equation_error(record: Run, protocol: IDIMProtocol, like: Plant) -> Plant:
    """The IDIM-LS fit of ``protocol`` on ``record`` as a plant (``like``'s encoder and
    sub-steps)."""
    from controllers.idim import fit as idim_fit

    f = idim_fit(y=record.y, u=record.u, ts=record.ts, protocol=protocol)
    return dataclasses.replace(like, **f.model.theta_, effects=f.model.effects_)


def diagnosed(record: Run, base: Plant) -> tuple[Plant, str]:
    """The diagnosis of ``base`` on ``record`` (causes selected and fitted on the whole of it):
    the extended plant and the causes it names."""
    from experiments.diagnosis import DiagnosisSettings, diagnose

    cut = int(round(0.75 * len(record)))  # its own gain report only; not used here
    d = diagnose(record, SimulationModel(base, None, "model", record.ts),
                 validation=record.slice(cut), settings=DiagnosisSettings())
    return d.extended, "; ".join(f.effect for f in d.findings)


@dataclass(frozen=True)
class Made:
    """A candidate made on one record: its structure's equation-error start, the names the
    diagnosis gave (if any) and the simulation-error fit."""

    name: str
    fit: oe.SimulationFit
    start: Plant
    note: str = ""
    cpu_s: float = field(default=0.0, compare=False)  # CPU (s) of the process that made it


def make_candidate(c: Candidate, record: Run, settings: BenchmarkSettings, like: Plant,
                   rng: np.random.Generator, published: Plant | None = None) -> Made:
    """``c`` made on ``record`` alone: the equation-error fit there, the structure, the starts
    (that fit, ``settings.perturbed_starts`` draws of ``rng`` around it, and ``published``'s
    values where given) and the simulation-error fit."""
    from clm_sim.effects.friction import FrictionAsymmetry

    protocol = dataclasses.replace(settings.published_procedure, offset=c.offset)
    eq = equation_error(record, protocol, like)
    note = ""
    if c.structure == "diagnosis":
        structure, note = diagnosed(record, eq)
    else:
        added = tuple(FrictionAsymmetry() for a in c.add if a == "friction_asymmetry")
        structure = dataclasses.replace(eq, effects=(*eq.effects, *added))
    structure = oe.merge_offsets(structure)
    names = oe.structure_parameters(structure)
    # A held term the diagnosis did not name on this data is not in the structure: nothing to
    # hold (the row's note names the terms it did name).
    hold = {k: oe.value(structure, k) for k in c.hold if k in names}
    free = [k for k in names if k not in hold]
    first = {k: oe.value(structure, k) for k in free}
    starts = [("equation-error fit", first)]
    starts += [(f"perturbed {i + 1}", oe.perturbed(first, rng))
               for i in range(settings.perturbed_starts)]
    if published is not None:
        theirs = oe.structure_parameters(oe.merge_offsets(published))
        starts.append(("published model", {k: oe.value(oe.merge_offsets(published), k)
                                           for k in free if k in theirs}))
    fit = oe.fit(structure, record, starts, hold=hold, init_samples=settings.init_samples,
                 max_nfev=settings.max_nfev)
    return Made(c.name, fit, structure, note)


# ----------------------------------------------------------------------------- results

@dataclass(frozen=True)
class Row:
    """One model on the benchmark: how it was made, its plant, its scores (m), and for a
    candidate its fit, its left-out-cycle RMSEs and the test RMSE of every start's end."""

    name: str
    made_from: str
    plant: Plant
    train_rmse_m: float
    test_rmse_m: float
    candidate: bool = False
    fit: oe.SimulationFit | None = None
    cycles_m: tuple[float, ...] = ()
    end_tests_m: tuple[float, ...] = ()
    note: str = ""
    chosen: bool = False
    conditioning: oe.Conditioning | None = None

    @property
    def mean_m(self) -> float:
        return float(np.mean(self.cycles_m)) if self.cycles_m else float("nan")

    @property
    def se_m(self) -> float:
        c = np.asarray(self.cycles_m)
        return float(c.std(ddof=1) / np.sqrt(len(c))) if len(c) > 1 else float("nan")

    @property
    def measured(self) -> bool:
        return self.fit is None or self.fit.measured

    def to_json(self) -> dict:
        return {"name": self.name, "made_from": self.made_from, "candidate": self.candidate,
                "chosen": self.chosen, "measured": self.measured,
                "train_rmse_m": self.train_rmse_m, "test_rmse_m": self.test_rmse_m,
                "left_one_cycle_out_rmse_m": list(self.cycles_m),
                "left_one_cycle_out_mean_m": self.mean_m if self.cycles_m else None,
                "end_points_test_rmse_m": list(self.end_tests_m), "note": self.note,
                "conditioning": (None if self.conditioning is None else
                                 self.conditioning.to_json()),
                "fit": None if self.fit is None else self.fit.to_json(),
                "model_file": f"models/{slug(self.name)}.json",
                "parameters": {k: oe.value(self.plant, k) for k in
                               oe.structure_parameters(self.plant)}}


def slug(name: str) -> str:
    return re.sub(r"[^a-z0-9]+", "_", name.lower()).strip("_")


@dataclass(frozen=True)
class Sensitivity:
    """For one model: per parameter its value, ``d(test RMSE)/d(theta)`` (m per unit), the
    range it takes over the training blocks and the test RMSE (m) at each end of that range
    (the others kept)."""

    model: str
    blocks: str
    rows: tuple[tuple[str, float, float, float, float, float, float], ...]

    def to_json(self) -> dict:
        return {"model": self.model, "blocks": self.blocks, "parameters": [
            dict(zip(("name", "value", "d_test_rmse_m_per_unit", "block_low", "block_high",
                      "test_rmse_at_low_m", "test_rmse_at_high_m"), r)) for r in self.rows]}


def rmse_on(test: Run, n0: int):
    def f(plant: Plant) -> float:
        try:
            return oe.training_rmse(plant, test, n0)
        except UserError:
            return float("nan")
    return f


def sensitivity(name: str, plant: Plant, blocks: dict[str, tuple[float, ...]], rmse, *,
                what: str) -> Sensitivity:
    """:class:`Sensitivity` of ``plant`` by central differences (a step of 1e-3 of each
    parameter's size; one-sided where the other side leaves the parameter's physical range,
    NaN where both do) and at the ends of its ``blocks`` values."""
    out = []
    for k in oe.structure_parameters(plant):
        v = oe.value(plant, k)
        h = 1e-3 * max(abs(v), oe._FLOOR[k])
        ok = [x for x in (v + h, v - h) if _safe(plant, k, x) is not plant]
        if len(ok) == 2:
            grad = (rmse(_safe(plant, k, v + h)) - rmse(_safe(plant, k, v - h))) / (2 * h)
        elif ok:
            grad = (rmse(_safe(plant, k, ok[0])) - rmse(plant)) / (ok[0] - v)
        else:
            grad = float("nan")
        b = blocks.get(k)
        if b:
            lo, hi = min(b), max(b)
            at = [rmse(_safe(plant, k, x)) for x in (lo, hi)]
        else:
            lo = hi = float("nan")
            at = [float("nan")] * 2
        out.append((k, v, grad, lo, hi, *at))
    return Sensitivity(name, what, tuple(out))


def end_score(plant: Plant, end: dict, rmse) -> float:
    """``rmse`` of ``plant`` with a start's end values; NaN where that end is outside the
    physical range (a start can stop where the fit's residual was the flat cost of an
    unphysical candidate)."""
    try:
        return rmse(oe.with_values(plant, end))
    except UserError:
        return float("nan")


def _safe(plant: Plant, k: str, x: float) -> Plant:
    try:
        return oe.with_values(plant, {k: x})
    except UserError:
        return plant


_DRIFT_NAMES = {"force_offset: offset": "offset", "stribeck: stribeck": "stribeck",
                "presliding: presliding": "presliding",
                "friction_asymmetry: asym_viscous": "asym_viscous",
                "parameter_mismatch: mass": "mass", "parameter_mismatch: viscous": "viscous",
                "parameter_mismatch: coulomb": "coulomb",
                "parameter_mismatch: stiffness": "stiffness"}


def drift_blocks(plant: Plant, drift: Drift) -> dict[str, tuple[float, ...]]:
    """The force-residual extension's parameters per contiguous training block: its value
    moved by each block's coefficient minus the whole record's (the drift analysis's joint
    fit); the cogging amplitude from each block's sine and cosine coefficients."""
    by = {c.name: c for c in drift.coefficients}
    out = {}
    for key, k in _DRIFT_NAMES.items():
        if key in by and k in oe.structure_parameters(oe.merge_offsets(plant)):
            c = by[key]
            out[k] = tuple(oe.value(oe.merge_offsets(plant), k) + b - c.value for b in c.blocks)
    if "cogging: cogging_sin" in by and "cogging: cogging_cos" in by:
        s, co = by["cogging: cogging_sin"], by["cogging: cogging_cos"]
        out["cogging"] = tuple(float(np.hypot(a, b)) for a, b in zip(s.blocks, co.blocks))
    return out


def initial_state_effect(plant: Plant, test: Run, n0: int) -> dict[str, float]:
    """The test RMSE (m) of ``plant`` with its initial velocity from the parabola through the
    first ``n0`` positions (the protocol here), from a backward difference over the last 5 of
    them, and over the last 2."""
    y, ts = test.y, test.ts
    out = {"parabola through the first samples": oe.training_rmse(plant, test, n0)}
    base = initial_state(y, ts, plant, n0)
    for k in (5, 2):
        v = (y[n0 - 1] - y[n0 - k]) / ((k - 1) * ts)
        state = InitialState(n0 - 1, float(y[n0 - 1]), float(v), base.bristles)
        x, _ = simulate_input(plant, test.u, ts, state)
        out[f"backward difference over the last {k} samples"] = float(
            np.sqrt(np.mean((x - y)[n0:] ** 2)))
    return out


def choose(rows: list[Row], selection: str = "minimum_mean") -> list[Row]:
    """``rows`` with ``chosen`` set on the one the rule ``selection`` picks: the candidate with
    the lowest mean left-out-cycle RMSE among those whose whole-record fit is a measurement
    (none where no candidate's fit is one)."""
    if selection != "minimum_mean":
        raise UserError(f"benchmark.selection: expected minimum_mean, got {selection!r}")
    eligible = [r for r in rows if r.candidate and r.measured and r.cycles_m]
    pick = min(eligible, key=lambda r: r.mean_m) if eligible else None
    return [dataclasses.replace(r, chosen=r is pick) for r in rows]


# ----------------------------------------------------------------------------- the study

def _make_task(payload) -> Made:
    """:func:`make_candidate` on a worker: ``(candidate, record, settings, like, seed
    sequence, published or None)``."""
    c, record, settings, like, seed, published = payload
    cpu = time.process_time()
    made = make_candidate(c, record, settings, like, np.random.default_rng(seed), published)
    return dataclasses.replace(made, cpu_s=time.process_time() - cpu)


def run_benchmark(settings: BenchmarkSettings, progress=print, workers: int = 1
                  ) -> BenchmarkRun:
    """Every row made from the training record and scored on both records; every candidate
    made again without each cycle and scored on it; the choice by the config's rule; the
    leak, the sensitivities, the initial-state effect and the drift analysis."""

    def path(key):
        p = Path(getattr(settings, key))
        if not p.exists():
            raise UserError(f"benchmark.{key}: file not found: {p} (paths are relative to the "
                            f"current folder {Path.cwd()})")
        return p

    train, test = (load_record(path(k), columns=settings.columns, scale=settings.scale)
                   for k in ("training", "test"))
    published = load_model(path("published_model")).plant
    n0 = settings.init_samples
    edges = cycle_edges(train.r, settings.cycles)  # before minutes of fits
    shortest = int(min(np.diff(edges)))
    if n0 + MIN_SCORED_SAMPLES > min(shortest, len(test)):
        raise UserError(f"benchmark.init_samples: {n0} initialization samples leave the "
                        f"shortest cycle ({shortest} samples) or the test record fewer than "
                        f"{MIN_SCORED_SAMPLES} to score")
    on_test = rmse_on(test, n0)
    on_train = rmse_on(train, n0)
    # One child stream per candidate and data set (whole record, then each fold), fixed order.
    seeds = np.random.SeedSequence(settings.seed).spawn(len(settings.candidates))
    streams = [s.spawn(settings.cycles + 1) for s in seeds]

    progress(f"whole training record ({len(train)} samples): reference rows")
    cpu = time.process_time()  # this process's; a worker's is counted by its tasks (the
    # pool's workers live on, so the operating system has not yet counted them as ended)
    procedure = equation_error(train, settings.published_procedure, published)
    extended, ext_note = diagnosed(train, published)
    rows = [Row("published model", "nothing (the published parameters)", published,
                on_train(published), on_test(published)),
            Row("published procedure (IDIM-LS)", "training record (equation error)", procedure,
                on_train(procedure), on_test(procedure)),
            Row("diagnosis-extended (force residual)", "training record (force residual)",
                extended, on_train(extended), on_test(extended), note=ext_note)]
    # Every (data set, candidate) fit is a task of its own, in ``workers`` processes: each
    # draws from its own stream, so the result does not depend on the number of workers.
    sets = [train] + [left_out(train, edges, k)[0] for k in range(settings.cycles)]
    tasks = [(j, i) for i in reversed(range(len(settings.candidates)))  # the longest first
             for j in range(len(sets))]
    payloads = [(settings.candidates[i], sets[j], settings, published, streams[i][j],
                 published if j == 0 else None) for j, i in tasks]
    progress(f"{len(tasks)} fits: every candidate on the whole record and without each of its "
             f"{settings.cycles} cycles ({workers} worker{'s' if workers > 1 else ''})")
    where = lambda j: "whole record" if j == 0 else f"without cycle {j}"  # noqa: E731
    done = {}
    for (j, i), m in zip(tasks, map_in_order(
            _make_task, payloads, workers,
            done=lambda n, k, m: progress(f"{n}/{len(tasks)} {m.name}, {where(tasks[k][0])}: "
                                          f"{m.fit.verdict()}"))):
        done[j, i] = m
    made = [done[0, i] for i in range(len(settings.candidates))]
    folds = []
    for k in range(settings.cycles):
        rest, cycle = left_out(train, edges, k)
        fold = {"procedure": equation_error(rest, settings.published_procedure, published)}
        fold.update({c.name: done[k + 1, i] for i, c in enumerate(settings.candidates)})
        folds.append((cycle, fold))
    for c, m in zip(settings.candidates, made):
        scores = tuple(rmse_on(cy, n0)(f[c.name].fit.plant) for cy, f in folds)
        ends = tuple(end_score(m.fit.plant, s.end, on_test) for s in m.fit.stops)
        try:
            cond = oe.conditioning(m.fit.plant, train, oe.structure_parameters(m.fit.plant), n0)
        except UserError:  # a coefficient at its bound of 0 cannot be moved both ways
            cond = None
        rows.append(Row(c.name, "training record (simulation error)", m.fit.plant,
                        m.fit.rmse_m, on_test(m.fit.plant), True, m.fit, scores, ends,
                        m.note, conditioning=cond))
        progress(f"{c.name}: left-out cycles "
                 + ", ".join(f"{x * 1e3:.2f}" for x in scores) + f" mm; test "
                 f"{rows[-1].test_rmse_m * 1e3:.2f} mm")
    pub_cycles = tuple(rmse_on(cy, n0)(published) for cy, _ in folds)
    proc_cycles = tuple(rmse_on(cy, n0)(f["procedure"]) for cy, f in folds)
    rows[0] = dataclasses.replace(rows[0], cycles_m=pub_cycles)
    rows[1] = dataclasses.replace(rows[1], cycles_m=proc_cycles)

    rows = choose(rows, settings.selection)
    pick = next((r for r in rows if r.chosen), None)

    progress("the leak of parameters identified on the whole record")
    estimation, held_out = split(train, 2 / 3, n0)
    part_proc = equation_error(estimation, settings.published_procedure, published)
    part_ext_old, _ = diagnosed(estimation, published)
    part_ext_new, _ = diagnosed(estimation, part_proc)
    on_held = rmse_on(held_out, n0)
    leak = {"held_out_samples": len(held_out),
            "published_model_on_held_out_m": on_held(published),
            "procedure_remade_on_held_out_m": on_held(part_proc),
            "published_model_cycles_mean_m": float(np.mean(pub_cycles)),
            "procedure_remade_cycles_mean_m": float(np.mean(proc_cycles)),
            "extension_from_published_on_held_out_m": on_held(part_ext_old),
            "extension_from_part_on_held_out_m": on_held(part_ext_new),
            "extension_from_published_theta": part_ext_old.theta(),
            "extension_from_part_theta": part_ext_new.theta()}

    progress("why the force-residual extension drifts; sensitivities")
    sim = lambda plant, run, source=None: simulate_record(  # noqa: E731
        SimulationModel(plant, None, "model", train.ts), run, init_samples=n0, source=source)
    drift = explain_drift(train, test, published, sim, estimation=estimation, held_out=held_out)
    drift = dataclasses.replace(drift, steady=tuple(cycle_friction(plateaus(train, edges))))
    sens = []
    for r in rows:
        structure = next((c.structure for c in settings.candidates if c.name == r.name), "")
        if r.candidate and (r.chosen or structure == "diagnosis"):
            i = [c.name for c in settings.candidates].index(r.name)
            blocks = {}
            for _, f in folds:
                p = f[r.name].fit.plant
                for k in oe.structure_parameters(p):
                    blocks.setdefault(k, []).append(oe.value(p, k))
            sens.append(sensitivity(r.name, r.plant, {k: tuple(v) for k, v in blocks.items()
                                                      if len(v) == len(folds)}, on_test,
                                    what=f"its {len(folds)} fits without one cycle "
                                    f"(candidate {i + 1})"))
    sens.append(sensitivity(rows[2].name, oe.merge_offsets(extended),
                            drift_blocks(extended, drift), on_test,
                            what="the force-residual fit on 5 contiguous blocks"))
    init = initial_state_effect(published, test, n0)
    return BenchmarkRun(rows=rows, pick=pick, leak=leak, drift=drift, sensitivity=sens,
                        initial_state=init,
                        cpu_s=time.process_time() - cpu + (
                            sum(m.cpu_s for m in done.values()) if workers > 1 else 0.0),
                        folds=[{k: (v.fit if isinstance(v, Made) else v.theta())
                                for k, v in f.items()} for _, f in folds])


@dataclass(frozen=True)
class BenchmarkRun:
    """What :func:`run_benchmark` computed: the rows (the published model first), the chosen
    candidate (None: none is a measurement), the leak of whole-record parameters (mm, m), the
    drift of the force-residual extension, the sensitivities, the initial-state methods' test
    RMSE (m), the CPU time (s) and, per left-out cycle, each candidate's simulation-error fit
    (the published procedure's parameters under ``procedure``)."""

    rows: list
    pick: Row | None
    leak: dict
    drift: Drift
    sensitivity: list
    initial_state: dict[str, float]
    cpu_s: float
    folds: list[dict]


# ----------------------------------------------------------------------------- the report
