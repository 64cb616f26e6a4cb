"""Write docs/performance.md from what the benchmarks print today, so the page cannot drift.

    python benchmarks/report.py [--quick] [--keep DIR] [--from DIR] [--out docs/performance.md]

Runs every benchmark below in a process of its own on this checkout (one BLAS thread), keeps what
it prints (``--keep DIR``, default ``results/benchmarks``), reads the figures from it and writes
the page: one table, each figure with the benchmark that prints it and the ratio it is judged by
(against python-control, against the arithmetic floor, against the 100 µs cycle of the 10 kHz
loop), under a generated header with the machine, the library versions, the commit and the load
average. Without ``--quick`` it also times the commands a user runs (the paper table, a study, the
test suite). ``--quick`` runs shorter benchmarks (fewer samples, seeds and repeats; no sweep, no
paper table, no commands: about five minutes on two idle cores) and the page says so.
``--only a,b`` runs those jobs and adds them to what the kept folder holds; ``--from DIR`` reads
what an earlier call kept instead of running anything.

Exit code 1 when a benchmark failed or printed nothing this script can read (the page is still
written and names it); 2 for a bad option.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import subprocess
import sys
import tempfile
import textwrap
import time
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CYCLE_S = 1e-4  # the 10 kHz loop's sample time
ONE_THREAD = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


@dataclass(frozen=True)
class Job:
    """One thing to time: a benchmark script (``script``) or a command (``argv``)."""
    name: str
    argv: tuple[str, ...]
    quick: tuple[str, ...] | None  # the --quick arguments; None: left out of --quick
    full: tuple[str, ...] = ()


BENCHMARKS = [
    Job("loop", ("benchmarks/bench_loop.py",), ("--samples", "100000", "--oracle-samples", "5000",
                                                 "--repeats", "5")),
    Job("substeps", ("benchmarks/bench_substeps.py",), ("--samples", "100000", "--repeats", "2")),
    Job("fit", ("benchmarks/bench_fit.py",), ("--seeds", "1", "--budget", "20")),
    Job("iteration_floor", ("benchmarks/bench_iteration_floor.py",), ("--repeats", "5",
                                                                      "--rounds", "3")),
    Job("export", ("benchmarks/bench_export.py",), ("--repeats", "1")),
    Job("diagnose", ("benchmarks/bench_diagnose.py",), ()),
    Job("exit", ("benchmarks/bench_exit.py",), ("--runs", "2")),
    Job("sweep", ("benchmarks/bench_sweep.py",), None),
    Job("table", ("benchmarks/bench_table.py",), None),
]
COMMANDS = [  # what a user runs; {tmp} is a scratch folder
    Job("cmd_table", ("-m", "experiments.cli", "run", "experiments/configs/paper_table.yaml",
                      "--out", "{tmp}/paper_table", "--quiet"), None),
    Job("cmd_study", ("-m", "experiments.cli", "study",
                      "experiments/configs/lambda0_iii_ten_draws.yaml", "--out",
                      "{tmp}/ten_draws", "--quiet"), None),
    Job("cmd_fast", ("-m", "pytest", "-q", "-n", "2", "-m", "not slow", "-p", "no:cacheprovider",
                     "--basetemp", "{tmp}/pytest_fast"), None),
    Job("cmd_suite", ("-m", "pytest", "-q", "-n", "auto", "-p", "no:cacheprovider",
                      "--basetemp", "{tmp}/pytest"), None),
]


@dataclass(frozen=True)
class Row:
    figure: str
    today: str
    judged_by: str
    ratio: str
    source: str


def run_job(job: Job, quick: bool, keep: Path, tmp: Path) -> dict:
    """Run ``job``, keep its stdout and stderr in ``keep``; its wall and CPU time (children)."""
    args = [a.replace("{tmp}", str(tmp)) for a in job.argv + (job.quick if quick else job.full)]
    env = {**os.environ, **ONE_THREAD, "PYTHONPATH": str(ROOT)}
    load = os.getloadavg()[0]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    print(f"report: {job.name} ...", file=sys.stderr, flush=True)
    proc = subprocess.run([sys.executable, *args], cwd=ROOT, env=env, capture_output=True,
                          text=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    (keep / f"{job.name}.out").write_text(proc.stdout)
    (keep / f"{job.name}.err").write_text(proc.stderr)
    meta = {"args": args, "code": proc.returncode, "wall_s": wall, "cpu_s": cpu,
            "quick": quick and job.quick is not None, "load": [load, os.getloadavg()[0]],
            "finished": f"{datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC", "commit": _commit()}
    print(f"report: {job.name} exit {proc.returncode}, {wall:.0f} s", file=sys.stderr,
          flush=True)
    return meta


def _num(pattern: str, text: str, group: int = 1) -> float:
    m = re.search(pattern, text, re.M)
    if m is None:
        raise ValueError(f"no match for {pattern!r}")
    return float(m.group(group).replace(",", ""))


def _kv(text: str) -> dict[str, float]:
    """``key=value`` pairs of a benchmark's last lines."""
    return {k: float(v) for k, v in re.findall(r"([A-Za-z_][\w.+-]*)=([-+0-9.eE]+)\b", text)}


def _pct(x: float) -> str:
    return f"{100 * x:.2g} %" if x < 0.1 else f"{100 * x:.0f} %"


def _x(x: float) -> str:
    return f"{x:,.0f}×" if x >= 100 else f"{x:.2g}×" if x < 10 else f"{x:.1f}×"


def rows_loop(out: str, err: str, args: list[str]) -> list[Row]:
    kv = _kv(out)
    samples = int(args[args.index("--samples") + 1]) if "--samples" in args else 400_000
    per = kv["product_s"] / samples
    src = "`bench_loop.py`"
    return [
        Row(f"closed loop, {samples:,} samples (default plant, PID, dither)",
            f"{kv['product_s']:.3g} s", "the same loop built from python-control",
            f"{_x(kv['speedup_vs_python_control'])} faster", src),
        Row("closed loop, one 10 kHz sample", f"{per * 1e9:.0f} ns", "the 100 µs cycle",
            f"{_pct(per / CYCLE_S)} of it", src),
        Row("closed loop against python-control's, true position", f"{kv['max_abs_diff_m']:.2g} m",
            "1e-9 m (1 % of an encoder count)", f"{kv['max_abs_diff_m'] / 1e-9:.2g} of it", src),
    ]


def rows_substeps(out: str, err: str, args: list[str]) -> list[Row]:
    lines = {int(line.split()[0]): line.split() for line in out.splitlines()
             if line.split() and line.split()[0].isdigit()}
    two = lines[2]
    return [Row("integration error at the default 2 sub-steps (halving the step)",
                f"{float(two[5]):.2g} encoder counts", "one encoder count (the accuracy rule)",
                f"{float(two[5]):.2g}×", "`bench_substeps.py`")]


def rows_fit(out: str, err: str, args: list[str]) -> list[Row]:
    src = "`bench_fit.py`"
    cpu = _num(r"^seed 0 product\s*:\s*([0-9.]+) s", out)
    rows = []
    names = {"least_squares": "`scipy.optimize.least_squares`, 2-point Jacobian",
             "lbfgs": "torch LBFGS to the same cost", "adam": "torch Adam to the same cost"}
    for key, label in names.items():
        m = re.search(rf"^\s+vs {key}\s*:\s*(>=)?([0-9.]+)x", out, re.M)
        if m:
            rows.append(Row("one PGNN fit (n_l = 16, λ = 0.01, weight decay 1e-5), seed 0",
                            f"{cpu:.2f} s CPU", label,
                            f"{'≥ ' if m.group(1) else ''}{float(m.group(2)):.1f}× faster", src))
    m = re.search(r"= ([0-9.]+) GFLOP/s; (\d+)% of a single-thread DGEMM \(([0-9.]+) GFLOP/s\)",
                  out)
    if m:
        rows.append(Row("one fit iteration's arithmetic rate", f"{m.group(1)} GFLOP/s",
                        f"a single-thread DGEMM ({m.group(3)} GFLOP/s)", f"{m.group(2)} %", src))
    return rows


def rows_iteration_floor(out: str, err: str, args: list[str]) -> list[Row]:
    src = "`bench_iteration_floor.py`"
    rows = []
    for n in (16, 8):
        m = re.search(rf"n_l =\s*{n}: product\s+([0-9.]+) ms, reference\s+[0-9.]+ ms, "
                      rf"restructured\s+([0-9.]+) ms", out)
        rows.append(Row(f"one LM iteration of a paper's-cost fit, n_l = {n}",
                        f"{float(m.group(1)):.1f} ms",
                        f"the least arithmetic known for it ({float(m.group(2)):.1f} ms)",
                        f"{float(m.group(1)) / float(m.group(2)):.2f}×", src))
    m = re.search(r"the table's ([0-9,]+) iterations[^:]*: ([0-9.]+) s at the product rate, "
                  r"[0-9.]+ s at the reference rate, ([0-9.]+) s at the restructured rate", out)
    product, floor = float(m.group(2)), float(m.group(3))
    rows.append(Row(f"the paper table's {m.group(1)} LM iterations (run)", f"{product:.0f} s",
                    f"the same at the least arithmetic ({floor:.0f} s)",
                    f"{product / floor:.2f}×", src))
    return rows


def rows_export(out: str, err: str, args: list[str]) -> list[Row]:
    kv = _kv(out)
    src = "`bench_export.py`"
    cases = [("LIP, C `clm_ff`", kv["lip_c_ns"]),
             ("PGNN n_l = 16, C `clm_ff` (AVX2 path)", kv["pgnn16_c_ns"]),
             ("PGNN n_l = 16, C streaming form", kv["pgnn16_c_stream_ns"]),
             ("PGNN n_l = 16, C `clm_ff`, `-DCLM_FF_PORTABLE`", kv["pgnn16_c_portable_ns"]),
             ("PGNN n_l = 16, C `clm_ff`, `-DCLM_FF_FLOAT`", kv["pgnn16_c_float_ns"]),
             ("PGNN n_l = 16, ONNX Runtime, one call", kv["onnx_call_us"] * 1e3),
             ("PGNN n_l = 16, ONNX Runtime, per window in batches", kv["onnx_batched_ns"]),
             ("PGNN n_l = 16, ONNX plain-MLP form, one call", kv["onnx_mlp_call_us"] * 1e3)]
    rows = [Row(f"exported feedforward: {what}",
                f"{ns / 1e3:.3g} µs" if ns >= 1e3 else f"{ns:.3g} ns", "the 100 µs cycle",
                f"{_pct(ns * 1e-9 / CYCLE_S)} of it", src) for what, ns in cases]
    rows.append(Row("exported PGNN against the product's force", f"{kv['tail_1e-15_err']:.2g}",
                    "the peak force", "(relative)", src))
    return rows


def rows_diagnose(out: str, err: str, args: list[str]) -> list[Row]:
    samples = int(_num(r"samples: (\d+)", out))
    cpu = _num(r"CPU ([0-9.]+) s", out)
    return [Row(f"`diagnose` on a {samples:,}-sample record (every candidate)", f"{cpu:.1f} s CPU",
                "the 5 s target", f"{cpu / 5:.2f}×", "`bench_diagnose.py`"),
            Row("`diagnose`, the same record", f"{cpu:.1f} s CPU", f"the record's length ({samples * CYCLE_S:.0f} s)",
                f"{_pct(cpu / (samples * CYCLE_S))} of it", "`bench_diagnose.py`")]


def rows_exit(out: str, err: str, args: list[str]) -> list[Row]:
    ended = _num(r"exit ended\s*: median ([0-9.]+) s", out)
    collected = _num(r"exit collected: median ([0-9.]+) s", out)
    return [Row("a finished command's exit (torch, control, scipy, numba loaded)",
                f"{ended:.2f} s", f"Python's own shutdown ({collected:.2f} s)",
                f"{collected / ended:.0f}× faster", "`bench_exit.py`")]


def rows_sweep(out: str, err: str, args: list[str]) -> list[Row]:
    serial = _num(r"serial\s+\(1 worker\):\s+([0-9.]+) s wall", out)
    parallel = _num(r"parallel \((\d+) workers\):\s+([0-9.]+) s wall", out, 2)
    workers = int(_num(r"parallel \((\d+) workers\)", out))
    tasks = int(_num(r"^(\d+) tasks", out))
    return [Row(f"a {tasks}-task sweep on {workers} workers", f"{parallel:.0f} s",
                f"the same on one worker ({serial:.0f} s)", f"{serial / parallel:.2f}× "
                f"(ideal {workers}×)", "`bench_sweep.py`")]


def rows_table(out: str, err: str, args: list[str]) -> list[Row]:
    kv = _kv(out)
    total, fits, its = kv["total_cpu_s"], kv["fits_s"], int(kv["iterations"])
    rows = [Row("the paper table on one core", f"{total:.0f} s CPU",
                f"its PGNN fits ({fits:.0f} s, {its:,} LM iterations run)",
                f"{_pct(fits / total)} fits", "`bench_table.py`")]
    if "floor_s" in kv:
        rows.append(Row("the paper table on one core, against its floor", f"{total:.0f} s CPU",
                        f"its iterations run at the least arithmetic ({kv['floor_s']:.0f} s; "
                        f"bar 1.5×)", f"{kv['bar_ratio']:.2f}×", "`bench_table.py`"))
    return rows


def rows_command(name: str, label: str, meta: dict) -> list[Row]:
    return [Row(label, f"{meta['wall_s'] / 60:.1f} min wall", f"its CPU ({meta['cpu_s']:.0f} s)",
                f"{meta['cpu_s'] / meta['wall_s']:.1f} cores busy", "`report.py` (commands)")]


READERS = {"loop": rows_loop, "substeps": rows_substeps, "fit": rows_fit,
           "iteration_floor": rows_iteration_floor, "export": rows_export,
           "diagnose": rows_diagnose, "exit": rows_exit, "sweep": rows_sweep,
           "table": rows_table}
COMMAND_LABELS = {"cmd_table": "`clm-sim run experiments/configs/paper_table.yaml`",
                  "cmd_study": "`clm-sim study experiments/configs/lambda0_iii_ten_draws.yaml`",
                  "cmd_fast": "the fast tier (`pytest -n 2 -m \"not slow\"`)",
                  "cmd_suite": "the test suite (`pytest -n auto`, as `.ci/run`)"}


def _git(*args: str) -> str:
    try:
        return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def _commit() -> str:
    dirty = " (with uncommitted changes)" if _git("status", "--porcelain",
                                                   "--untracked-files=no") else ""
    return _git("rev-parse", "--short", "HEAD") + dirty


def provenance(jobs: dict, source: str) -> list[str]:
    """The generated header: what the figures depend on besides the code."""
    sys.path.insert(0, str(ROOT))
    from clm_sim.numerics import environment

    import clm_sim

    env = environment()
    env["versions"]["clm-sim"] = clm_sim.__version__  # the code run, whatever pip installed
    versions = ", ".join(f"{k} {v}" for k, v in env["versions"].items())
    try:
        import onnxruntime
        versions += f", onnxruntime {onnxruntime.__version__}"
    except ImportError:
        pass
    cc = subprocess.run(["cc", "--version"], capture_output=True, text=True).stdout
    commits = sorted({job.get("commit", "unknown") for job in jobs.values()})
    return ["<!-- provenance: generated by benchmarks/report.py -->",
            "| provenance | |", "|---|---|",
            f"| written | {datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC by "
            f"`python benchmarks/report.py` ({source}) |",
            "| measured | " + "; ".join(
                f"{name} {job.get('finished', '?')}{' (--quick)' if job.get('quick') else ''}"
                for name, job in jobs.items()) + " |",
            f"| commit measured | {', '.join(commits)} |",
            f"| CPU | {env['cpu']}, {os.cpu_count()} logical cores, {env['machine']} |",
            "| load average (1 min) | " + "; ".join(
                f"{name} {job['load'][0]:.1f}–{job['load'][1]:.1f}" for name, job in jobs.items()
                if "load" in job) + " |",
            f"| kernels | {env['kernels_pinned']} |",
            f"| versions | {versions} |",
            f"| C compiler | {cc.splitlines()[0] if cc else 'none'} |",
            "<!-- end provenance -->"]


STATIC = """
## What the benchmarks measure

Every benchmark prints its figures and asserts nothing; the tests never time anything. CPU
times are of one thread (one BLAS thread, the process's own clock), the fair figure on a shared
machine; wall times say how busy the machine was, which the load average above records.

| benchmark | what it runs |
|---|---|
| `bench_loop.py` | the closed loop (default plant with its effects, default PID, r1 repeated, dither) with `clm_sim.loop.simulate` against the identical loop built from python-control (a discrete-time `NonlinearIOSystem` running the pure-Python twin of the compiled plant step, `pid.discrete`, `input_output_response`; its time scaled from a shorter horizon) |
| `bench_substeps.py` | the same loop at 2 to 32 integration sub-steps per sample: time, and how far halving the sub-step moves the true position |
| `bench_fit.py` | one PGNN fit on the paper table's training data against `scipy.optimize.least_squares` with a finite-difference Jacobian, torch LBFGS and Adam run to the product's final cost, and the code it replaced (checked out from git); one iteration's GFLOP/s |
| `bench_iteration_floor.py` | one Levenberg-Marquardt iteration of a paper's-cost fit against the least arithmetic known for the same step (same normal matrix and gradient, checked); the page's table's iterations run at both rates |
| `bench_table.py` | the paper table's rows in one process on one core: CPU per stage (start-up, training run, fits, replays, references and features, figures, writing), LM iterations run and reused, stops; its CPU against the restructured rate times the iterations run (the bar: 1.5×) |
| `bench_export.py` | the exported feedforward per call: C at `-O2` (default build with its AVX2 path, `-DCLM_FF_PORTABLE`, `-DCLM_FF_FLOAT`), ONNX Runtime per call and batched; its error against the product; what `export-ff --filter-tail` trades |
| `bench_diagnose.py` | `diagnose` on a 400,000-sample record of an emulated machine, every candidate family searched |
| `bench_sweep.py` | a 60-task sweep (6 λ × 2 n_l × 5 seeds) on one worker and on two; the two tables must be identical |
| `bench_exit.py` | how long a process with the numerical libraries loaded takes to end: as Python ends it, with its heap frozen, and as `clm-sim` ends (`os._exit` after the exit handlers) |
| `bench_optimizer.py`, `bench_reference_sim.py`, `profile_point.py`, `same_minimizer.py`, `stress_signals.py` | checks run after a change, not figures of this page: the optimizer against plain LM, the test records' fingerprints, a profile point's convergence, the fits of another commit, signals at random moments |

## Why the loop is fast

The loop is sequential (each sample depends on the last through the controller, the encoder and
the stick-slip logic), so it is a plain Python loop compiled by numba (`clm_sim/kernel.py`), in
float64 without `fastmath`, so that its arithmetic is that of its pure-Python twin. The plant
step is inlined into the loop, compiled without numba's reference counting (which cost two
thirds of the time on a dozen parameter arrays), and allocates nothing; loop invariants are
computed once per run; the Stribeck term is skipped where `exp` underflows to 0.0. What remains
per sub-step is one `sin` (the force ripple), the cable carrier's polynomial and a dozen
multiply-adds. The first call on a fresh clone compiles (about 3 s of CPU) and caches the result.
"""


def write_page(rows: list[Row], failed: list[str], jobs: dict, source: str, out: Path) -> None:
    quick = [name for name, job in jobs.items() if job.get("quick")]
    paragraphs = [
        "Today's figures, each with the benchmark that prints it and what it is judged by. This "
        "page is written by `python benchmarks/report.py` from the benchmarks' own output; edit "
        "the script, not the page. The machine, the versions, the load and when each figure was "
        "measured are in the generated table below the figures; the figures move with the load "
        "of a shared machine."]
    if quick:
        paragraphs.append("Run with `--quick` (shorter runs: fewer samples, seeds and repeats): "
                          + ", ".join(f"`{n}`" for n in quick) + ".")
    head = ["# Performance", ""]
    for text in paragraphs:
        head += textwrap.wrap(text, width=100, break_on_hyphens=False) + [""]
    if failed:
        head += textwrap.wrap(f"**Not read** (the benchmark failed or printed nothing this script "
                              f"reads): {', '.join(failed)}.", width=100) + [""]
    table = ["| figure | today | judged by | ratio | printed by |", "|---|---|---|---|---|"]
    table += [f"| {r.figure} | {r.today} | {r.judged_by} | {r.ratio} | {r.source} |"
              for r in rows]
    text = "\n".join(head + table + [""] + provenance(jobs, source)) + "\n" + STATIC
    out.write_text(text, encoding="utf-8")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="shorter runs, no sweep/table/commands")
    ap.add_argument("--keep", type=Path, default=ROOT / "results" / "benchmarks",
                    help="folder for what each benchmark prints (default results/benchmarks)")
    ap.add_argument("--from", dest="source", type=Path, default=None,
                    help="read a kept folder instead of running the benchmarks")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "performance.md")
    ap.add_argument("--only", default="", help="comma-separated job names (default: all); "
                    "added to the kept folder's earlier measurements")
    args = ap.parse_args(argv)

    keep = args.source or args.keep
    if args.source is None:
        keep.mkdir(parents=True, exist_ok=True)
        jobs = [j for j in BENCHMARKS + ([] if args.quick else COMMANDS)
                if j.quick is not None or not args.quick]
        if args.only:
            jobs = [j for j in jobs if j.name in args.only.split(",")]
        metas = {}
        if args.only and (keep / "meta.json").exists():  # add to what an earlier call measured
            metas = json.loads((keep / "meta.json").read_text())["jobs"]
        with tempfile.TemporaryDirectory(prefix="clm_report_") as tmp:
            for job in jobs:
                metas[job.name] = run_job(job, args.quick, keep, Path(tmp))
                meta = {"jobs": metas}
                (keep / "meta.json").write_text(json.dumps(meta, indent=1))
    else:
        try:
            meta = json.loads((keep / "meta.json").read_text())
        except (OSError, ValueError) as exc:
            print(f"report.py: error: {keep / 'meta.json'}: {exc}", file=sys.stderr)
            return 2

    rows, failed = [], []
    for name, job in meta["jobs"].items():
        out = (keep / f"{name}.out").read_text()
        err = (keep / f"{name}.err").read_text()
        try:
            if job["code"] != 0:
                raise ValueError(f"exit {job['code']}")
            rows += (READERS[name](out, err, job["args"]) if name in READERS
                     else rows_command(name, COMMAND_LABELS[name], job))
        except (ValueError, KeyError, AttributeError, IndexError) as exc:
            failed.append(f"`{name}` ({exc})")
    source = "measured" if args.source is None else f"read from {args.source.name}/"
    write_page(rows, failed, meta["jobs"], source, args.out)
    print(f"wrote {args.out} ({len(rows)} figures" + (f"; not read: {', '.join(failed)}"
                                                      if failed else "") + ")")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
