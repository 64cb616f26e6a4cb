"""Turn an experiment config into results: training run, identification, replays, table, figures.

    config -> plant + PID + references -> closed-loop training run (dithered, logged)
           -> LIP (and PGNN) identification -> replay on each reference -> table, figures

Everything is written into a temporary sibling of the output folder and moved into place at the
end, so an interrupted or failed run never leaves a half-written result.
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import numpy as np
import yaml

from clm_sim.errors import UserError
from clm_sim.numerics import environment, versions
from clm_sim.outdir import atomic_folder
from clm_sim.records.write import save_npz
from experiments.config import ExperimentConfig, resolved
from experiments.report import table_json, table_md
from experiments.results import TableRow
from experiments.stats.comparisons import comparisons
from experiments.table import RecordRow, Row
from experiments.testbed import Progress, Testbed


def slug(text: str) -> str:
    return re.sub(r"[^a-z0-9]+", "_", text.lower()).strip("_")


MAX_NAME = 200  # characters of a row's file name (params/<name>_seed<k>.json: <= 255 bytes)


def check_row_names(config: ExperimentConfig) -> None:
    """Rows whose names give the same file name (``Net A`` and ``net-a``) would overwrite each
    other's ``params/``; a name too long for a file fails only when written: both refused
    before the work."""
    seen: dict[str, int] = {}
    for i, spec in enumerate(config.feedforwards):
        name = slug(spec.label())
        if len(name.encode()) > MAX_NAME:
            raise UserError(f"feedforwards[{i}].name: {len(name)} characters as a file name; "
                            f"at most {MAX_NAME}")
        if name in seen and spec.kind != "none":
            raise UserError(f"feedforwards[{i}].name: {spec.label()!r} is saved as "
                            f"params/{name}_seed<k>, as feedforwards[{seen[name]}]; give the "
                            f"rows names that differ in letters or digits")
        seen.setdefault(name, i)


def run_experiment(config: ExperimentConfig, out: Path, *, quiet: bool = False,
                   config_path: str | None = None) -> list[Row | RecordRow]:
    """Run ``config`` and write its results into ``out`` (replaced atomically). Returns rows."""
    progress = Progress(quiet)
    try:
        preflight(config)
    except UserError as exc:  # name the file: the config loaded fine, its values do not fit
        raise UserError(f"{config_path}: {exc}" if config_path else str(exc)) from None
    subdirs = ("runs", "params", "figures")
    if config.data is not None:  # a run on records saves only its PGNN models
        subdirs = ("params",) if any(s.kind == "pgnn" for s in config.feedforwards) else ()
    records = (config.data.training, config.data.validation) if config.data else ()
    with atomic_folder(out, what="clm-sim results",
                       subdirs=subdirs, inputs=(config_path, *records)) as tmp:
        try:
            rows = _run(config, tmp, progress, config_path)
        except UserError as exc:  # a diverged loop, a record too short: name the config
            text = str(exc)
            if config_path and not text.startswith(config_path):
                text = f"{config_path}: {text}"
            raise UserError(text) from None
    progress(f"results in {out}/ (table.md, table.json, figures/)")
    return rows


def preflight(config: ExperimentConfig) -> None:
    """Cheap cross-field checks that would otherwise fail only after the training run.

    Raises ``UserError`` for PID design parameters out of range, a filter at or above the
    Nyquist frequency or a training reference that cannot be repeated (sizes, counts and time
    spans are checked when the config is built: :data:`experiments.config.LIMITS`). The design
    itself (0.3 s) is not made here: an unstable design is a result (a sweep records it as a
    failed task).
    """
    from controllers.pid import _check as check_pid_design

    check_row_names(config)
    if config.data is not None:  # the records own their sample time; no simulation runs
        for which in ("training", "validation"):
            path = getattr(config.data, which)
            if path is not None and not Path(path).exists():
                raise UserError(f"data.{which}: file not found: {path} (paths are relative "
                                f"to the current folder {Path.cwd()})")
        return
    check_pid_design(config.plant.mass, config.plant.viscous, config.plant.stiffness,
                     config.controller, config.ts)
    nyquist = 0.5 / config.ts
    for key in ("regression_lowpass_hz", "position_lowpass_hz"):
        value = getattr(config.features, key)
        if value is not None and value >= nyquist:
            raise UserError(f"features.{key}: {value:g} Hz is at or above the Nyquist frequency "
                            f"{nyquist:g} Hz of ts = {config.ts:g} s")
    points = config.references[config.training.reference].points_m
    if config.training.repeats > 1 and points[0] != points[-1]:  # as training_reference, unsampled
        raise UserError(f"training.repeats: reference {config.training.reference!r} must end "
                        f"where it starts to be repeated")


def _run_records(config: ExperimentConfig, out: Path | None, progress) -> list[RecordRow]:
    """The rows of a config with a ``data:`` section (:mod:`experiments.records.fit`); with
    ``out`` also table.json, table.md and the fitted models."""
    from experiments.records import fit as record_fit
    result = record_fit.compute(config, progress)
    if out is not None:
        for row, models in zip(result.rows, result.models):
            for s, model in enumerate(models):
                if model is not None:
                    model.save(out / "params" / f"{slug(row.label)}_seed{s}")
        (out / "table.json").write_text(json.dumps({**result.to_json(),
                                                    "environment": environment()}, indent=1))
        (out / "table.md").write_text(record_fit.to_markdown(result.rows, result.comparisons))
    return result.rows


def run_task(config: ExperimentConfig, *, progress=None) -> list[Row | RecordRow]:
    """The table rows of ``config``, computed without writing any file (one sweep task)."""
    preflight(config)
    return _run(config, None, progress or Progress(quiet=True), None)


def _run(config: ExperimentConfig, out: Path | None, progress, config_path) -> list:
    """Compute the rows of ``config``; with ``out`` also write runs, parameters and figures."""
    if out is not None:
        (out / "config.resolved.yaml").write_text(yaml.safe_dump(resolved(config),
                                                                 sort_keys=False))
    if config.data is not None:  # measured records instead of the simulation
        return _run_records(config, out, progress)
    tb = Testbed(config, progress=progress)
    try:
        pid = tb.pid
    except UserError as exc:
        raise UserError(f"{config_path or 'config'}: controller: {exc}") from None
    progress(pid.summary())
    if out is not None:
        (out / "controller.json").write_text(json.dumps({
            "crossover_hz": pid.crossover_hz, "phase_margin_deg": pid.phase_margin_deg,
            "gain_margin_db": pid.gain_margin_db, "b": pid.b.tolist(), "a": pid.a.tolist(),
            "kp": pid.kp, "ki": pid.ki, "kd": pid.kd, "tau_d": pid.tau_d}, indent=1))

    train = tb.training_run()
    train.meta.update(versions=versions(), config_path=config_path)
    if out is not None:
        save_npz(train, out / "runs" / "training.npz")
    lip = tb.fit_lip(train)
    if out is not None:
        (out / "params" / "lip.json").write_text(json.dumps(lip.to_json(), indent=1))

    if tb.warnings and out is not None:  # (a sweep's task keeps them in its rows)
        from experiments.records.suspicions import warn
        warn(config_path or "config", tb.warnings)
    rows, shown = [], {}
    for spec in config.feedforwards:
        result = tb.evaluate(spec, train, lip)
        row = TableRow.from_result(result).row()
        if tb.warnings:  # every row rests on the LIP (a PGNN starts from it): said with each
            row = row.with_extra(warnings=list(tb.warnings))
        rows.append(row)
        if out is not None:
            shown[spec.label()] = result.first_replays
            for name, run in result.first_replays.items():
                save_npz(run, out / "runs" / f"replay_{slug(spec.label())}_{name}.npz")
            if spec.kind == "pgnn":
                for s, model in enumerate(result.models):
                    model.save(out / "params" / f"{slug(spec.label())}_seed{s}")

    if out is None:
        return rows
    if config.truth is not None:  # diagnose the model against the emulated machine
        from experiments.diagnosis.emulate import diagnose_emulated
        diagnose_emulated(tb, record=train, out=out / "diagnosis", progress=progress)
    pairs = comparisons(rows)
    (out / "table.json").write_text(table_json.to_json(rows, environment=environment(),
                                                       pairs=pairs))
    (out / "table.md").write_text(table_md.to_markdown(rows, pairs=pairs))
    (out / "table.csv").write_text(table_md.to_csv(rows))
    from experiments import (
        plots,  # matplotlib only where figures are drawn (not in tasks)
    )
    for name in config.replay:
        plots.save(plots.tracking_figure(shown, name, rows=rows),
                   out / "figures" / f"tracking_{name}.png")
        if any(spec.kind != "none" for spec in config.feedforwards):
            plots.save(plots.feedforward_figure(shown, name),
                       out / "figures" / f"feedforward_{name}.png")
    return rows
