"""The ``clm-sim`` command: ``run`` an experiment config, ``study`` or ``sweep`` one, ``identify``
a LIP from a record, ``diagnose`` a model against it, ``export`` a logged run, ``export-ff`` a
feedforward to C or ONNX, ``compare`` a fresh table with a published one.

This module only parses the command line and calls the library; how the process ends (user
mistakes: one line, exit 2; Ctrl-C 130, SIGTERM 143; an internal error: one line, exit 1, the
traceback with ``--debug``) is :mod:`experiments.processes.process`. ``sweep`` exits with 1 when
some tasks failed (the table is still written and lists them). Data that look wrong but may be right
give one warning line each. docs/cli.md states it all.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import clm_sim
from clm_sim.numerics import one_thread_per_process, pin_portable_kernels
from experiments.cli import arguments
from experiments.processes import process
def _cmd_run(args) -> int:
    from clm_sim.schema import load_yaml
    from experiments.config import load_config, refuse_other_commands
    from experiments.records.suspicions import config_warnings
    from experiments.runner import run_experiment

    data = load_yaml(args.config)
    refuse_other_commands(data, args.config)
    config = load_config(args.config, data)
    _warn(args.config, config_warnings(config))
    out = Path(args.out) if args.out else Path("results") / Path(args.config).stem
    run_experiment(config, out, quiet=args.quiet, config_path=str(args.config))
    from experiments.report.screen import run_summary
    print(run_summary(out), end="")  # read back from what the run wrote
    return 0


def _load(path, args):
    """The record at ``path``, read with the command's ``--columns`` and ``--scale``."""
    from clm_sim.records.read import load_record, parse_pairs

    return load_record(path, columns=parse_pairs(args.columns, "--columns", number=False),
                       scale=parse_pairs(args.scale, "--scale", number=True))


def _cmd_identify(args) -> int:
    from experiments.cli.identify import command
    return command(args, load=_load)


def _cmd_simulate(args) -> int:
    from experiments.cli.simulate import command
    return command(args, load=_load)


def _cmd_export(args) -> int:
    from clm_sim.records.write import convert

    out, samples = convert(args.run, args.to, args.out)
    print(f"wrote {out} ({samples} samples)")
    return 0


def _cmd_export_ff(args) -> int:
    from experiments.cli.export_ff import export

    arguments.check_source_date_epoch(os.environ)  # the export's date, read in its trace
    files = export(args.model, args.to, args.out, ts=args.ts, filter_tail=args.filter_tail,
                   prefix=args.prefix, max_force=args.max_force, max_slew=args.max_slew,
                   max_velocity=args.max_velocity, max_acceleration=args.max_acceleration,
                   position_range=args.position_range, limits_from=args.limits_from,
                   no_limits=args.no_limits, count_m=args.count_m, onnx_form=args.onnx_form)
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
    print("\n".join(outcome.lines(sweep.grid, out)))
    return outcome.exit_code


def _warn(path, lines: list[str]) -> None:
    from experiments.records.suspicions import warn
    warn(path, lines)


def _cmd_study(args) -> int:
    from experiments.studies import runner

    # Only the study the config names is imported (each loads its own libraries: matplotlib,
    # scipy.signal, torch), so a config refused for its kind costs none of them.
    return runner.main(args.config, args.out, workers=args.workers, quiet=args.quiet)


def _cmd_diagnose(args) -> int:
    from experiments.diagnosis.checked import diagnose_files

    out = Path(args.out) if args.out else Path("results") / f"diagnosis_{Path(args.data).stem}"
    result = diagnose_files(args.data, out=out, read=lambda path: _load(path, args),
                            model_path=args.model, validate=args.validate,
                            regression_lowpass_hz=args.regression_lowpass_hz,
                            warn=lambda lines: _warn(args.data, lines))
    print(result.summary())
    print(f"report in {out}/report.md")
    return 0


def _cmd_compare(args) -> int:
    from experiments.stats.agreement import verdict

    lines, code = verdict(Path(args.expected), Path(args.fresh))
    print("\n".join(lines))
    return code


class _Parser(argparse.ArgumentParser):
    """argparse with its errors as every other mistake of the command line: one line,
    ``clm-sim: error: <command>: <what>`` naming the option, exit 2 (no usage block; ``--help``
    has it). ``add_subparsers`` builds the commands' parsers with this class too."""

    def error(self, message: str):
        command = self.prog.removeprefix("clm-sim").strip()
        if message.endswith("expected one argument"):  # argparse reads "-1e-12" as an option
            message += " (a value that starts with '-' is written --option=VALUE)"
        line = f"clm-sim: error: {command + ': ' if command else ''}{message}"
        self.exit(2, (line if len(line) <= 1000 else line[:997] + "...") + "\n")


def parser() -> argparse.ArgumentParser:
    p = _Parser(
        prog="clm-sim", description="Simulate a coreless linear motor under PID feedback, "
        "identify its LIP and PGNN feedforwards, and diagnose a model against measured records.")
    p.add_argument("--version", action="version", version=f"clm-sim {clm_sim.__version__}")
    p.add_argument("--debug", action="store_true",
                   help="on an internal error, print the Python traceback too")
    sub = p.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run an experiment config and write table and figures")
    arguments.config(run, "experiment YAML file")
    run.set_defaults(func=_cmd_run)

    ident = sub.add_parser("identify", help="identify the LIP feedforward from a record")
    arguments.record(ident)
    ident.add_argument("--out", help="folder for lip.json (default results/identify/<data name>)")
    arguments.cutoff(ident, "(default: a config's, FeatureMap.regression_lowpass_hz; 0 = none)")
    arguments.protocol(ident)
    ident.set_defaults(func=_cmd_identify)
    simulate = sub.add_parser("simulate", help="simulate a model open loop from a record's "
                              "input and score it against the measured position")
    simulate.add_argument("model", help="identify's lip.json, a diagnosis.json (its extended "
                          "model) or a model YAML (plant:, effects)")
    arguments.record(simulate)
    arguments.simulation(simulate)
    simulate.set_defaults(func=_cmd_simulate)
    export = sub.add_parser("export", help="convert a logged run (.npz) to CSV or MATLAB .mat")
    export.add_argument("run", help="run record, e.g. results/lip_baseline/runs/training.npz")
    export.add_argument("--to", choices=("csv", "mat"), default="csv", help="target format")
    export.add_argument("--out", help="target file (default: the run's name with the new suffix)")
    export.set_defaults(func=_cmd_export)
    eff = sub.add_parser("export-ff", help="export a feedforward as C (clm_ff.h, clm_ff.c) or "
                         "ONNX (clm_ff.onnx) for a real-time target")
    arguments.export_ff(eff)
    eff.set_defaults(func=_cmd_export_ff)
    sweep = sub.add_parser("sweep", help="run a grid of experiments (a config with a 'sweep:' "
                           "section) in parallel, resumably")
    arguments.config(sweep, "experiment YAML file with a sweep: grid",
                      "; re-running into it resumes")
    sweep.add_argument("--workers", type=arguments.workers, help="parallel tasks (default: all cores)")
    sweep.add_argument("--backend", choices=("local", "dask"), default="local",
                       help="local processes, or Dask (pip install 'clm-sim[cluster]')")
    sweep.add_argument("--scheduler", help="Dask scheduler address, with --backend dask "
                       "(default: a LocalCluster)")
    sweep.add_argument("--retry-failed", action="store_true",
                       help="recompute tasks stored as failed")
    sweep.set_defaults(func=_cmd_sweep)
    diag = sub.add_parser("diagnose", help="show what the simulation gets wrong on a measured "
                          "record, name the cause, extend the model, measure the gain")
    arguments.record(diag)
    diag.add_argument("--model", help="model YAML (plant:, optional controller:), a lip.json "
                      "from identify or run, a diagnosis.json (its extended model) or an "
                      "experiment config (default: the default CLM)")
    diag.add_argument("--validate", help="validation record (default: the final 25 %% of DATA)")
    diag.add_argument("--out", help="output folder (default results/diagnosis_<data name>)")
    arguments.cutoff(diag, "(default: the diagnosis's narrower band, "
                     "DiagnosisSettings.regression_lowpass_hz; capped at 0.2/ts)")
    diag.set_defaults(func=_cmd_diagnose)
    study = sub.add_parser("study", help="the PGNN extrapolation study: lambda sweep, report.md "
                           "with figures")
    arguments.config(study, "study YAML file (an experiment config plus 'study:')")
    study.add_argument("--workers", type=arguments.workers, help="parallel cells of a failure_map: study "
                       "(default: all cores)")
    study.set_defaults(func=_cmd_study)
    compare = sub.add_parser("compare", help="does a fresh table.json reproduce a published "
                             "table (Markdown) within the cross-machine tolerance?")
    compare.add_argument("expected", help="Markdown file whose first results table is the "
                         "published one, e.g. docs/results/paper_table.md")
    compare.add_argument("fresh", help="table.json of a fresh run")
    compare.set_defaults(func=_cmd_compare)
    return p


def main(argv=None) -> int:
    """The command line; ``argv=None`` means a real process (``sys.argv``), which receives its
    signals in a thread of its own and after an interruption ends at once
    (:mod:`experiments.processes.process`)."""
    program = argv is None
    if program:
        process.receive_signals()
    pin_portable_kernels()  # before numpy, scipy or torch load (clm_sim.numerics)
    one_thread_per_process()  # the same bits whatever the cores or thread variables
    args = parser().parse_args(argv)
    # Files only, never a window: the one place where clm-sim picks matplotlib's backend.
    os.environ["MPLBACKEND"] = "Agg"
    source = next((getattr(args, k) for k in ("config", "data", "model", "run", "fresh")
                   if getattr(args, k, None)), None)
    return process.run(lambda: args.func(args), program=program, name=args.command,
                       source=source, debug=args.debug)

