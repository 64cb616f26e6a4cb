"""The ``clm-sim`` command: ``run`` an experiment config, ``study`` or ``sweep`` one, ``identify``
a LIP from a record, ``diagnose`` a model against it, ``export`` a logged run, ``export-ff`` a
feedforward to C or ONNX, ``compare`` a fresh table with a published one.

User mistakes (``UserError``) print one line on stderr and exit with code 2, never a traceback.
``sweep`` exits with 1 when some tasks failed (the table is still written and lists them).
Ctrl-C (exit 130) and SIGTERM (exit 143) stop a command the same way: nothing half-written stays.
Data that look wrong but may be right give one warning line each. docs/cli.md states it all.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import signal
import sys
import threading
from pathlib import Path

import clm_sim
from clm_sim.errors import UserError
from clm_sim.numerics import pin_portable_kernels


def _cmd_run(args) -> int:
    from clm_sim.schema import load_yaml
    from experiments.config import load_config
    from experiments.runner import run_experiment
    from experiments.suspicions import plant_warnings
    from experiments.table import to_markdown

    data = load_yaml(args.config)
    for section, command in (("sweep", "sweep"), ("study", "study"), ("failure_map", "study")):
        if section in data:
            raise UserError(f"{args.config}: has a '{section}:' section; run it with "
                            f"'clm-sim {command} {args.config}'")
    config = load_config(args.config)
    for where, plant in (("plant", config.plant), ("truth", config.truth)):
        if plant is not None:
            _warn(args.config, plant_warnings(plant, where))
    out = Path(args.out) if args.out else Path("results") / Path(args.config).stem
    rows = run_experiment(config, out, quiet=args.quiet, config_path=str(args.config))
    if config.identifiability is not None or config.data is not None:
        print((out / "table.md").read_text(), end="")  # with the sections beyond the rows
    else:
        print(to_markdown(rows), end="")
    return 0


def _record_arguments(p: argparse.ArgumentParser) -> None:
    """The record ``data`` and how its columns map onto a record (``--columns``, ``--scale``)."""
    p.add_argument("data", help="record: CSV with header t,r,y,u (SI units), .npz or .mat")
    p.add_argument("--columns", help="signal=column names in the files, e.g. y=qm,r=qg,u=vir")
    p.add_argument("--scale", help="signal=factor or signal=scalar-variable of the file, "
                   "e.g. u=gtau or y=0.001")


def _load(path, args):
    """The record at ``path``, read with the command's ``--columns`` and ``--scale``."""
    from clm_sim.record import load_record

    return load_record(path, columns=_pairs(args.columns, "--columns", number=False),
                       scale=_pairs(args.scale, "--scale", number=True))


def _cmd_identify(args) -> int:
    from clm_sim.features import FeatureMap
    from clm_sim.outdir import atomic_write, check_writable, write_error
    from controllers.lip import LIPFeedforward
    from experiments.suspicions import record_warnings
    from experiments.table import THETA_UNITS

    out = Path(args.out) if args.out else Path("results") / "identify" / Path(args.data).stem
    check_writable(out)  # before the work: a result that cannot be written is not computed
    run = _load(args.data, args)
    cutoff = args.regression_lowpass_hz
    try:
        features = FeatureMap() if cutoff is None else \
            FeatureMap(regression_lowpass_hz=None if cutoff <= 0 else cutoff)
        lip = LIPFeedforward(features=features).fit(y=run.y, u=run.u, ts=run.ts)
    except UserError as exc:  # name the file and the option
        raise UserError(f"{args.data}: {exc}" + (" (--regression-lowpass-hz)"
                                                 if "lowpass" in str(exc) else "")) from None
    values = {**lip.theta_, **lip.std_}
    bad = [name for name, value in values.items() if not math.isfinite(value)]
    if bad or not math.isfinite(lip.residual_rms_):
        raise UserError(f"{args.data}: the fit gives non-finite parameters "
                        f"({', '.join(sorted(set(bad))) or 'residual'}); the record's values are "
                        f"too large or degenerate for a least-squares fit")
    _warn(args.data, record_warnings(run, lip))
    for name, value in lip.theta_.items():
        print(f"{name:10s} {value:12.6g} {THETA_UNITS[name]:6s} (std {lip.std_[name]:.2g})")
    print(f"residual rms {lip.residual_rms_:.4g} N over {len(run)} samples at "
          f"{1 / run.ts:g} Hz")
    try:
        atomic_write(out / "lip.json", json.dumps({**lip.to_json(), "source": str(args.data)},
                                                  indent=1, allow_nan=False))
    except OSError as exc:
        raise write_error(out, exc) from None
    print(f"wrote {out / 'lip.json'} (a model for clm-sim diagnose --model)")
    return 0


def _cmd_export(args) -> int:
    from clm_sim.record import load_record, save_csv, save_mat

    run = load_record(args.run)
    out = Path(args.out) if args.out else Path(args.run).with_suffix("." + args.to)
    if out.suffix.lower() != "." + args.to:
        raise UserError(f"{out}: --to {args.to} needs a .{args.to} file name")
    (save_csv if args.to == "csv" else save_mat)(run, out)
    print(f"wrote {out} ({len(run)} samples)")
    return 0


def _cmd_export_ff(args) -> int:
    from experiments.export_ff import export

    files = export(args.model, args.to, args.out, ts=args.ts, filter_tail=args.filter_tail,
                   prefix=args.prefix, max_force=args.max_force, max_slew=args.max_slew)
    print(f"wrote {', '.join(str(f) for f in files)} (see docs/export.md)")
    return 0


def _cmd_sweep(args) -> int:
    from experiments.sweeps.grid import load_sweep
    from experiments.sweeps.run import check_output, run_sweep

    sweep = load_sweep(args.config)  # every grid point checked before anything runs
    out = Path(args.out) if args.out else Path("results") / Path(args.config).stem
    check_output(out)
    outcome = run_sweep(sweep, out, backend=args.backend, workers=args.workers,
                        scheduler=args.scheduler, retry_failed=args.retry_failed,
                        quiet=args.quiet)
    print(f"{outcome.total} tasks: {outcome.computed} run now, {outcome.reused} reused from "
          f"{out}/tasks, {len(outcome.failures)} failed, {outcome.unfinished} unfinished")
    for f in outcome.failures:
        point = ", ".join(f"{k}={f[k]}" for k in sweep.grid) or "config"
        print(f"  FAILED {point}: {f['error']}")
    if outcome.stopped:
        print(f"sweep stopped: {outcome.stopped}; run the same command again to resume")
    if not outcome.unfinished:
        print(f"results in {out}/ (table.md, table.json, figures/)")
    return outcome.exit_code


def _warn(path, lines: list[str]) -> None:
    """Data that look wrong but may be right: one stderr line each; the command goes on."""
    for line in lines:
        print(f"clm-sim: warning: {path}: {line}", file=sys.stderr)


def _record_warnings(record, model) -> list[str]:
    """:func:`experiments.suspicions.record_warnings` of a record against a diagnosis model."""
    from controllers.lip import LIPFeedforward
    from experiments.suspicions import record_warnings

    try:
        lip = LIPFeedforward().fit(y=record.y, u=record.u, ts=record.ts)
    except UserError:  # the diagnosis says why the record cannot be fitted
        lip = None
    plant = getattr(model, "plant", None)
    return record_warnings(record, lip, model_mass=getattr(plant, "mass", None))


def _pairs(text: str | None, option: str, number: bool) -> dict:
    """``"y=qm,u=vir"`` -> ``{"y": "qm", "u": "vir"}`` (values as numbers where they parse)."""
    out = {}
    for item in filter(None, (text or "").split(",")):
        key, sep, value = item.partition("=")
        if not sep or not key.strip() or not value.strip():
            raise UserError(f"{option}: expected NAME=VALUE pairs separated by commas, "
                            f"got {item!r}")
        value = value.strip()
        if number:
            try:
                value = float(value)
            except ValueError:
                pass
        out[key.strip()] = value
    return out


def _diagnosis_model(path, ts: float):
    """The simulation's model: the default CLM without a file, else ``load_model``'s reading."""
    from experiments.diagnosis.model import SimulationModel, load_model

    return SimulationModel() if path is None else load_model(path, ts)


def _cmd_study(args) -> int:
    from clm_sim.schema import load_yaml
    if "failure_map" in load_yaml(args.config):  # where lambda = 0 fails: its own study
        from experiments.studies.failure_map import main
        return main(args.config, args.out, workers=args.workers, quiet=args.quiet)
    from experiments.studies.extrapolation import load_study, run_study

    config, study = load_study(args.config)  # checked as clm-sim run checks, before any work
    out = Path(args.out) if args.out else Path("results") / Path(args.config).stem
    run_study(config, study, out, quiet=args.quiet)
    print((out / "report.md").read_text(), end="")
    return 0


def _cmd_diagnose(args) -> int:
    from clm_sim.outdir import check_output_folder
    from experiments.diagnosis import DiagnosisSettings, diagnose
    from experiments.diagnosis.report import write

    out = Path(args.out) if args.out else Path("results") / f"diagnosis_{Path(args.data).stem}"
    check_output_folder(out, marker="diagnosis.json", what="a diagnosis")  # before the work
    record = _load(args.data, args)
    validation = _load(args.validate, args) if args.validate else None
    model = _diagnosis_model(args.model, record.ts)
    settings = DiagnosisSettings() if args.regression_lowpass_hz is None else \
        DiagnosisSettings(regression_lowpass_hz=args.regression_lowpass_hz)
    _warn(args.data, _record_warnings(record, model))
    try:
        result = diagnose(record, model, validation=validation, settings=settings)
    except UserError as exc:  # name the file the error is about
        text = str(exc)
        raise UserError(text if text.startswith(str(args.data)) or (
            args.validate and text.startswith(str(args.validate))) else f"{args.data}: {text}") \
            from None
    write(result, out)
    print(result.summary())
    print(f"report in {out}/report.md")
    return 0


def _cmd_compare(args) -> int:
    from experiments.agreement import compare_files

    mismatches = compare_files(Path(args.expected), Path(args.fresh))
    for m in mismatches:
        print(m)
    if mismatches:
        print(f"{len(mismatches)} cell(s) outside the cross-machine tolerance "
              f"(docs/reproducibility.md)")
        return 1
    print(f"{args.fresh} reproduces the table in {args.expected} within the cross-machine "
          f"tolerance")
    return 0


def _workers(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}")
    return value


def _config_arguments(p: argparse.ArgumentParser, config: str, out: str = "") -> None:
    """The config file, ``--out`` (default ``results/<config name>``) and ``--quiet``."""
    p.add_argument("config", help=config)
    p.add_argument("--out", help=f"output folder (default results/<config name>){out}")
    p.add_argument("--quiet", action="store_true", help="no progress lines")


def _cutoff_argument(p: argparse.ArgumentParser, default: str) -> None:
    """``--regression-lowpass-hz``: the parallel filter's cut-off, named as in a config's
    ``features:`` and in the Python API (``--lowpass-hz`` still accepted, not shown)."""
    p.add_argument("--regression-lowpass-hz", type=float, metavar="HZ",
                   help=f"cut-off of the zero-phase parallel filter of the regression, Hz "
                   f"{default}")
    p.add_argument("--lowpass-hz", type=float, dest="regression_lowpass_hz",
                   help=argparse.SUPPRESS)


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="clm-sim", description="Simulate a coreless linear motor under PID feedback, "
        "identify its LIP and PGNN feedforwards, and diagnose a model against measured records.")
    p.add_argument("--version", action="version", version=f"clm-sim {clm_sim.__version__}")
    sub = p.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run an experiment config and write table and figures")
    _config_arguments(run, "experiment YAML file")
    run.set_defaults(func=_cmd_run)
    ident = sub.add_parser("identify", help="identify the LIP feedforward from a record")
    _record_arguments(ident)
    ident.add_argument("--out", help="folder for lip.json (default results/identify/<data name>)")
    _cutoff_argument(ident, "(default: a config's, FeatureMap.regression_lowpass_hz; 0 = none)")
    ident.set_defaults(func=_cmd_identify)
    export = sub.add_parser("export", help="convert a logged run (.npz) to CSV or MATLAB .mat")
    export.add_argument("run", help="run record, e.g. results/lip_baseline/runs/training.npz")
    export.add_argument("--to", choices=("csv", "mat"), default="csv", help="target format")
    export.add_argument("--out", help="target file (default: the run's name with the new suffix)")
    export.set_defaults(func=_cmd_export)
    eff = sub.add_parser("export-ff", help="export a feedforward as C (clm_ff.h, clm_ff.c) or "
                         "ONNX (clm_ff.onnx) for a real-time target")
    eff.add_argument("model", help="params/lip.json or params/<row>_seed<k>.pt of a run, "
                     "identify's lip.json, or a diagnosis.json")
    eff.add_argument("--to", required=True, help="c or onnx")
    eff.add_argument("--out", required=True, help="output folder (replaced as a whole)")
    eff.add_argument("--ts", type=float, help="sample time (s), where the file carries none")
    eff.add_argument("--filter-tail", type=float, metavar="TOL",
                     help="PGNN: cut the feature filter where its discarded tail is below TOL of "
                          "its sum (default 1e-15, exact to rounding; larger: a shorter window "
                          "and look-ahead, less exact; see docs/export.md)")
    eff.add_argument("--prefix", help="names of the public symbols, macros and files "
                     "(default clm_ff; two exports with different prefixes link together)")
    eff.add_argument("--max-force", type=float, metavar="N", help="C: |force| limit (N)")
    eff.add_argument("--max-slew", type=float, metavar="N_PER_S",
                     help="C: the stream's rate limit (N/s; changeable at run time)")
    eff.set_defaults(func=_cmd_export_ff)
    sweep = sub.add_parser("sweep", help="run a grid of experiments (a config with a 'sweep:' "
                           "section) in parallel, resumably")
    _config_arguments(sweep, "experiment YAML file with a sweep: grid",
                      "; re-running into it resumes")
    sweep.add_argument("--workers", type=_workers, help="parallel tasks (default: all cores)")
    sweep.add_argument("--backend", choices=("local", "dask"), default="local",
                       help="local processes, or Dask (pip install 'clm-sim[cluster]')")
    sweep.add_argument("--scheduler", help="Dask scheduler address (default: a LocalCluster)")
    sweep.add_argument("--retry-failed", action="store_true",
                       help="recompute tasks stored as failed")
    sweep.set_defaults(func=_cmd_sweep)
    diag = sub.add_parser("diagnose", help="show what the simulation gets wrong on a measured "
                          "record, name the cause, extend the model, measure the gain")
    _record_arguments(diag)
    diag.add_argument("--model", help="model YAML (plant:, optional controller:), a lip.json "
                      "from identify or run, or an experiment config (default: the default CLM)")
    diag.add_argument("--validate", help="validation record (default: the final 25 %% of DATA)")
    diag.add_argument("--out", help="output folder (default results/diagnosis_<data name>)")
    _cutoff_argument(diag, "(default: the diagnosis's narrower band, "
                     "DiagnosisSettings.regression_lowpass_hz; capped at 0.2/ts)")
    diag.set_defaults(func=_cmd_diagnose)
    study = sub.add_parser("study", help="the PGNN extrapolation study: lambda sweep, report.md "
                           "with figures")
    _config_arguments(study, "study YAML file (an experiment config plus 'study:')")
    study.add_argument("--workers", type=_workers, help="parallel cells of a failure_map: study "
                       "(default: all cores)")
    study.set_defaults(func=_cmd_study)
    compare = sub.add_parser("compare", help="does a fresh table.json reproduce a published "
                             "table (Markdown) within the cross-machine tolerance?")
    compare.add_argument("expected", help="Markdown file whose first results table is the "
                         "published one, e.g. docs/results/paper_table.md")
    compare.add_argument("fresh", help="table.json of a fresh run")
    compare.set_defaults(func=_cmd_compare)
    return p


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised like Ctrl-C so that every clean-up (temporary result folders, sweep
    workers) runs the same way."""


_said = False  # the line of an interruption is printed (a second signal prints no other)
_CODES = {signal.SIGINT: 130, signal.SIGTERM: 128 + signal.SIGTERM}
_WORDS = {signal.SIGINT: "interrupted", signal.SIGTERM: "terminated"}


def _end_now(signum, frame):
    """A second Ctrl-C or SIGTERM while the first is being handled: end at once, whatever the
    clean-up was doing; the workers are killed, the temporary folder and lock removed first.
    Does nothing if the process is already being ended (:func:`_exit_now`)."""
    if not _ENDING.acquire(blocking=False):
        return
    workers = sys.modules.get("experiments.workers")
    if workers is not None:
        workers.kill_all()
    outdir = sys.modules.get("clm_sim.outdir")
    if outdir is not None:
        outdir.abandon()
    if not _said:
        os.write(2, f"clm-sim: {_WORDS[signum]}\n".encode())
    os._exit(_CODES[signum])


def _signalled(signum, frame):
    """The first Ctrl-C or SIGTERM: unwind (every ``finally`` removes what it was writing); a
    second signal ends the process at once."""
    _unwinding.set()
    signal.signal(signal.SIGINT, _end_now)
    signal.signal(signal.SIGTERM, _end_now)
    raise Terminated if signum == signal.SIGTERM else KeyboardInterrupt


def _receive_signals() -> None:
    """A real process takes Ctrl-C and SIGTERM in a thread of its own: they are blocked in every
    other thread (blocked here before any library starts one), so none is lost to a library's
    thread or while workers start (:data:`experiments.workers.SPAWNING`). The first is passed
    to the main thread as if it had come there (it unwinds the command); if the main thread has
    not taken it within ``ANSWER_S`` (inside a long computation), or on a second signal, or one
    after the command ended, this thread ends the process at once (:func:`_end_now`)."""
    stops = set(_CODES)
    signal.pthread_sigmask(signal.SIG_BLOCK, stops)
    # The main thread is poked with a signal of its own (a real one: it also ends a blocking
    # wait there), and takes it as the signal received.
    signal.signal(_POKE, lambda _, frame: _signalled(_state["signum"], frame))
    main = threading.main_thread().ident

    def receive():
        while True:
            signum = signal.sigwait(stops)
            if _state["exiting"]:
                continue  # the main thread is ending the process (under its own guard)
            if _state["signalled"] or _state["done"]:
                _end_now(signum, None)
                continue  # (only if the main thread is already ending the process)
            _state["signalled"], _state["signum"] = True, signum
            workers = sys.modules.get("experiments.workers")
            with workers.SPAWNING if workers is not None else contextlib.nullcontext():
                signal.pthread_kill(main, _POKE)
            if not _unwinding.wait(ANSWER_S):
                # The main thread is inside a long call that releases the GIL (a simulation
                # kernel, a fit) and writes no file meanwhile: end from here.
                _end_now(signum, None)

    threading.Thread(target=receive, daemon=True, name="clm-sim-signals").start()


_state = {"signalled": False, "done": False, "exiting": False, "signum": signal.SIGINT}
_POKE = getattr(signal, "SIGUSR1", None)  # thread-directed, from the signal thread to main
_unwinding = threading.Event()  # set when the main thread has taken the first signal
ANSWER_S = 0.5  # s: how long the main thread may take to start unwinding after a signal
_ENDING = threading.Lock()  # held by whoever ends the process: _exit_now or _end_now


def main(argv=None) -> int:
    """The command line; ``argv=None`` means a real process (``sys.argv``), which receives its
    signals in a thread of its own and after an interruption ends at once, without waiting at
    interpreter exit for anything."""
    global _said
    _said = False
    program = argv is None
    if program and hasattr(signal, "pthread_sigmask") and _POKE is not None:
        _receive_signals()
    # Before numpy, scipy or torch load: their AVX2 kernels on every x86-64 CPU that has them, so
    # a fit sums in the same order on another CPU (clm_sim.numerics; CLM_SIM_NATIVE_KERNELS=1 opts out).
    pin_portable_kernels()
    args = parser().parse_args(argv)
    # Files only, never a window: the one place where clm-sim picks matplotlib's backend.
    os.environ["MPLBACKEND"] = "Agg"
    main_thread = threading.current_thread() is threading.main_thread()
    previous = {sig: signal.signal(sig, _signalled) for sig in _CODES} if main_thread else {}
    code = None
    try:
        code = args.func(args)
        return code
    except UserError as exc:
        code = 2
        print(f"clm-sim: error: {_one_line(str(exc))}", file=sys.stderr)
        return code
    except KeyboardInterrupt as exc:
        sig = signal.SIGTERM if isinstance(exc, Terminated) else signal.SIGINT
        code = _CODES[sig]
        _stop_workers()
        print(f"clm-sim: {_WORDS[sig]}", file=sys.stderr, flush=True)
        _said = True
        return code
    except OSError as exc:  # the last net: a file the checks above did not foresee, one line
        code = 2
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"clm-sim: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return code
    finally:
        if program and code in (130, 143):
            _exit_now(code)
        if program and main_thread:
            # Done: a late signal (results written, interpreter exiting) ends with its code.
            _state["done"] = True
            signal.signal(signal.SIGINT, _end_now)
            signal.signal(signal.SIGTERM, _end_now)
        else:
            for sig, handler in previous.items():
                signal.signal(sig, handler)


def _exit_now(code: int) -> None:
    """End an interrupted process without interpreter shutdown, which may wait on pool threads
    (and so hang, or print a late traceback): only multiprocessing's own exit clean-up runs
    (it releases the pools' semaphores; the workers are already ended), under a one-second
    guard."""
    import multiprocessing.util

    _ENDING.acquire()  # not both this and a second signal's _end_now
    _state["exiting"] = True
    guard = threading.Timer(1.0, os._exit, (code,))
    guard.daemon = True
    guard.start()
    with contextlib.suppress(Exception):
        multiprocessing.util._exit_function()
    _release_semaphores()
    with contextlib.suppress(Exception):
        sys.stdout.flush()
        sys.stderr.flush()
    os._exit(code)


def _release_semaphores() -> None:
    """Unlink the pools' semaphores (multiprocessing's resource tracker, which exits by itself
    when this process has ended, then has nothing left to remove)."""
    import multiprocessing.util

    with contextlib.suppress(Exception):
        multiprocessing.util._run_finalizers(0)


def _stop_workers() -> None:
    """End the PGNN fit pool, if this command started one (sweep workers end in
    :func:`experiments.workers.run_local`)."""
    workers = sys.modules.get("experiments.workers")
    if workers is not None:
        workers.stop_fits()


def _one_line(text: str, limit: int = 1000) -> str:
    """A message as one line of at most ``limit`` characters (a value quoted in it is cut)."""
    text = " ".join(text.split())
    return text if len(text) <= limit else text[:limit] + " ..."


if __name__ == "__main__":
    sys.exit(main())
