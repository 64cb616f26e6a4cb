"""The EMPS benchmark as a :class:`~experiments.studies.protocol.Study`: its config's name and
path, its result as ``benchmark.json`` holds it, and the models and figures it writes beside the
report (the computation, the table and the report are :mod:`experiments.studies.emps.benchmark`).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

from clm_sim.errors import UserError
from clm_sim.records.read import load_record
from clm_sim.schema import to_plain
from experiments.model_files import SimulationModel
from experiments.records import output_error as oe
from experiments.records.simulation import simulate_record
from experiments.studies.emps.benchmark import BenchmarkRun, run_benchmark, slug
from experiments.studies.emps.report import plot_errors, table, to_markdown, verdict
from experiments.studies.emps.settings import BenchmarkSettings, load_benchmark
from experiments.studies.emps.drift import plot_drift
from experiments.studies.protocol import Study


@dataclass(frozen=True)
class Named:
    """What :data:`STUDY` reads besides the settings: the config's name and path."""

    name: str
    path: Path


@dataclass(frozen=True)
class BenchmarkResult:
    """The study's result as ``benchmark.json`` holds it: the config's name, the command, the
    settings and :func:`run_benchmark`'s result (rows, choice, leak, sensitivities, drift)."""

    name: str
    command: str
    settings: BenchmarkSettings
    run: BenchmarkRun

    def to_json(self) -> dict:
        settings, result = self.settings, self.run
        pick = result.pick
        return {"name": self.name, "command": self.command, "selection": settings.selection,
                "rule": "the lowest mean left-out-cycle RMSE among the candidates whose "
                        "whole-record fit is a measurement (benchmark.selection in the config, "
                        "with its reason)",
                "chosen": None if pick is None else pick.name,
                "rows": [r.to_json() for r in result.rows],
                "baselines": [dataclasses.asdict(b) for b in settings.baselines],
                "init_samples": settings.init_samples, "cycles": settings.cycles,
                "leak": result.leak, "initial_state_test_rmse_m": result.initial_state,
                "sensitivity": [s.to_json() for s in result.sensitivity],
                "cpu_s": result.cpu_s, "drift": result.drift.to_json()}


def _load(path) -> tuple[Named, BenchmarkSettings]:
    name, settings = load_benchmark(path)
    return Named(name, Path(path)), settings


def _compute(named: Named, settings: BenchmarkSettings, *, workers: int,
             progress) -> tuple[BenchmarkResult, None]:
    try:
        result = run_benchmark(settings, progress, workers)
    except UserError as exc:
        text = str(exc)
        raise UserError(text if text.startswith(str(named.path)) else
                        f"{named.path}: {text}") from None
    return BenchmarkResult(named.name, f"clm-sim study {named.path}", settings, result), None


def _files(result: BenchmarkResult, folder: Path, scene=None) -> None:
    """The models (``models/*.json``) and the figures (``folder``: the test-record errors of
    the published model, the chosen one and the diagnosis's; the drift)."""
    from experiments import plots

    settings, rows, pick = result.settings, result.run.rows, result.run.pick
    test = load_record(settings.test, columns=settings.columns, scale=settings.scale)
    ts = test.ts

    def sim(plant):
        return simulate_record(SimulationModel(plant, None, "model", ts), test,
                               init_samples=settings.init_samples)

    for r in rows:
        info = oe.model_file(r.plant, ts, name=r.name, description=f"EMPS: {r.made_from}")
        path = folder.parent / "models" / f"{slug(r.name)}.json"
        path.parent.mkdir(exist_ok=True)
        path.write_text(json.dumps(info, indent=1))
    traces = [("published model", sim(rows[0].plant))]
    if pick is not None:
        traces.append((f"chosen: {pick.name}", sim(pick.plant)))
    traces.append((rows[2].name, sim(rows[2].plant)))
    plots.save(plot_errors(traces).figure, folder / "test_errors.png")
    if result.run.drift.traces:
        plots.save(plot_drift(result.run.drift).figure, folder / "drift.png")


STUDY = Study(
    kind="emps_benchmark", section="benchmark", what="a benchmark", settings=BenchmarkSettings,
    load=_load, compute=_compute, result=BenchmarkResult, result_file="benchmark.json",
    report=lambda result, settings: to_markdown(result.run, settings, result.command),
    figures=_files, workers=lambda: 1,
    resolved=lambda named, settings: {"name": named.name, "benchmark": to_plain(settings)},
    inputs=lambda path, s: (path, s.training, s.test, s.published_model),
    summary=lambda result, out: "\n".join([*table(result.run.rows, result.settings), "",
                                           *verdict(result.run, result.settings)]))
