"""Running a sweep: one independent task per grid point (:mod:`experiments.sweeps.grid`), stored
resumably, and one table at the end.

Tasks are stored by :mod:`experiments.sweeps.store` under a hash of their resolved config and the code
version, so a re-run (after a crash, ``SIGKILL`` included) computes only unfinished tasks. A task
that fails (diverged loop, unstable PID design, ...) is stored with its error and the others go
on. The output folder holds ``tasks/`` (one JSON per task), ``table.json`` (the shared schema,
each row extended with the swept keys and its task key, plus a ``failures`` list), ``table.md``
(mean ± std over the swept seeds, then the rows of every task), ``table.csv`` and
``figures/mae_vs_<key>.png`` (MAE against each swept key, mean and spread over seeds).
"""

from __future__ import annotations

import json
import re
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from clm_sim.errors import UserError
from clm_sim.outdir import (MANIFEST, atomic_write, check_writable, entries, manifest,
                            output_lock, write_manifest)
from clm_sim.schema import build
from experiments.config import ExperimentConfig
from experiments.processes.workers import cores
from experiments.report import table_md
from experiments.table import Row, read_row
from experiments.runner import run_task, slug
from experiments.stats.seeds import POSITION, over_seeds
from experiments.sweeps.grid import Sweep
from experiments.sweeps.store import ResultStore
from experiments.testbed import Progress


@dataclass
class Outcome:
    """What a sweep run did: task counts, the failures and the aggregated rows."""

    total: int
    computed: int = 0
    reused: int = 0
    failures: list = field(default_factory=list)
    unfinished: int = 0
    stopped: str | None = None
    rows: list = field(default_factory=list)

    @property
    def exit_code(self) -> int:
        """0 when every task succeeded, 1 when some failed or remain unfinished."""
        return 1 if (self.failures or self.unfinished) else 0

    def lines(self, grid, out: Path) -> list[str]:
        """What ``clm-sim sweep`` prints at the end (``grid``: the swept keys)."""
        lines = [f"{self.total} tasks: {self.computed} run now, {self.reused} reused from "
                 f"{out}/tasks, {len(self.failures)} failed, {self.unfinished} unfinished"]
        for f in self.failures:
            point = ", ".join(f"{k}={f[k]}" for k in grid) or "config"
            lines.append(f"  FAILED {point}: {f['error']}")
        if self.stopped:
            lines.append(f"sweep stopped: {self.stopped}; run the same command again to resume")
        if not self.unfinished:
            lines.append(results_line(out))
        return lines


def results_line(out: Path) -> str:
    """The line that says where a finished sweep's results are: its tables, and its figures
    where it drew any (a sweep over seeds alone draws none)."""
    names = ["table.md", "table.json", "table.csv"]
    if (out / "figures").is_dir():
        names.append("figures/")
    return f"results in {out}/ ({', '.join(names)})"


def execute(config_plain: dict) -> dict:
    """Run one task in a worker: ``{"status": "ok", "rows"}`` or ``{"status": "failed",
    "error"}``. Never raises for the task's own failure, so one bad point cannot stop a sweep."""
    start = time.perf_counter()
    try:
        config = build(ExperimentConfig, config_plain, "config")
        if any(spec.kind == "pgnn" for spec in config.feedforwards):
            import torch
            torch.set_num_threads(1)  # one core per task; the sweep runs tasks in parallel
        rows = [row.to_json() for row in run_task(config)]
        json.dumps(rows, allow_nan=False)  # a NaN or inf in the results is a failure
        return {"status": "ok", "rows": rows, "elapsed_s": time.perf_counter() - start}
    except Exception as exc:  # recorded, not raised: the sweep goes on with the other tasks
        text = " ".join(str(exc).split()) or type(exc).__name__
        return {"status": "failed", "error": f"{type(exc).__name__}: {text}",
                "elapsed_s": time.perf_counter() - start}


# ----------------------------------------------------------------------------- running

WHAT = "clm-sim sweep results"  # the kind named in a sweep folder's manifest (clm_sim.outdir)
# What a sweep writes in its folder (the manifest aside): a sweep resumes into a folder that
# holds only these, under a manifest of its kind; anything else is the user's and is refused.
_OWN = re.compile(r"(\.lock|sweep\.resolved\.yaml|table\.(json|md|csv)|tasks|figures"
                  r"|tasks/[0-9a-f]{24}\.json|figures/mae_vs_[A-Za-z0-9_.-]+\.png"
                  r"|(tasks/|figures/)?\.[^/]+\.tmp\d+)")


def check_output(out: Path) -> None:
    """Refuse an output folder that exists and is not a sweep's (before anything is written):
    a folder that is not empty must carry a sweep's manifest and hold only what a sweep
    writes, so a resumed sweep writes over nothing of the user's."""
    check_writable(out)
    out = Path(out)
    if out.is_dir() and any(out.iterdir()):
        listing = manifest(out)
        if listing is None or listing["what"] != WHAT:
            raise UserError(f"{out}: output folder exists and does not hold clm-sim sweep "
                            f"results (no sweep manifest {MANIFEST}); choose another --out")
        folders, files = entries(out)
        for rel in (*folders, *files):
            if not _OWN.fullmatch(rel):
                raise UserError(f"{out}: holds {rel}, which a sweep does not write; move it or "
                                f"choose another --out")
    for name in (".lock", "tasks", "figures", "sweep.resolved.yaml", "table.json", "table.md",
                 "table.csv"):
        if (out / name).is_symlink():  # a sweep writes nothing through a link in its folder
            raise UserError(f"{out / name}: a symbolic link; clm-sim writes no file through a "
                            f"link inside --out (remove it, or choose another --out)")


def _lock(out: Path):
    try:
        import fcntl
    except ImportError:  # Windows: no advisory lock
        return None
    # O_NOFOLLOW: a .lock that is a link to another file must not truncate that file
    fd = os.open(out / ".lock", os.O_WRONLY | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0), 0o644)
    fh = os.fdopen(fd, "w")
    try:
        fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        fh.close()
        raise UserError(f"{out}: another sweep is writing into this folder") from None
    return fh


def run_sweep(sweep: Sweep, out: Path, *, backend: str = "local", workers: int | None = None,
              scheduler: str | None = None, retry_failed: bool = False,
              quiet: bool = False) -> Outcome:
    """Run the unfinished tasks of ``sweep`` into ``out`` and aggregate all of them."""
    out = Path(out)
    check_output(out)
    if workers is None:
        workers = cores()
    if workers < 1:
        raise UserError(f"--workers: expected an integer >= 1, got {workers}")
    if scheduler and backend != "dask":  # the local backend has no scheduler to connect to
        raise UserError(f"--scheduler {scheduler}: a Dask scheduler's address; it needs "
                        f"--backend dask (the backend is {backend})")
    say = Progress(quiet)
    out.resolve().parent.mkdir(parents=True, exist_ok=True)
    with output_lock(out.resolve(), out):  # beside --out, as run, study and diagnose take it
        return _run_sweep(sweep, out, say, backend=backend, workers=workers,
                          scheduler=scheduler, retry_failed=retry_failed)


def _run_sweep(sweep: Sweep, out: Path, say, *, backend, workers, scheduler,
               retry_failed) -> Outcome:
    from experiments.sweeps.backends import BACKENDS

    check_output(out)  # again, under the lock
    out.mkdir(parents=True, exist_ok=True)
    lock = _lock(out)
    try:
        write_manifest(out, WHAT)  # the folder is a sweep's from its first file on
        store = ResultStore(out / "tasks").open()
        store.on_invalid = lambda path, why: say(f"{path}: {why}; the task is recomputed")
        atomic_write(out / "sweep.resolved.yaml", yaml.safe_dump(
            {"base": sweep.base, "grid": sweep.grid, "code_version": sweep.code_version},
            sort_keys=False))
        outcome = Outcome(total=len(sweep.tasks))
        todo, seen = [], set()
        for task in sweep.tasks:
            stored = store.get(task.key)
            if task.key in seen:
                continue
            seen.add(task.key)
            if stored is None or (retry_failed and stored["status"] == "failed"):
                todo.append(task)
        outcome.reused = len(seen) - len(todo)
        if todo:
            for name in ("table.json", "table.md", "table.csv"):
                (out / name).unlink(missing_ok=True)  # a stale table must not outlive its grid
        say(f"{len(sweep.tasks)} tasks, {outcome.reused} already stored, {len(todo)} to run "
            f"on {backend} ({min(workers, max(len(todo), 1))} workers)")
        run = BACKENDS[backend]
        kwargs = {"scheduler": scheduler} if backend == "dask" else {}
        try:
            for i, result in run(execute, [t.config for t in todo],
                                 min(workers, max(len(todo), 1)), **kwargs):
                task = todo[i]
                store.put(task.key, {**result, "key": task.key, "overrides": task.overrides,
                                     "code_version": sweep.code_version,
                                     "config": task.config})
                outcome.computed += 1
                point = ", ".join(f"{k}={v}" for k, v in task.overrides.items()) or "config"
                status = ("ok" if result["status"] == "ok" else
                          "FAILED " + result["error"])
                say(f"{outcome.computed}/{len(todo)} {point}: {status} "
                    f"({result['elapsed_s']:.1f} s)")
        except UserError:
            raise
        except Exception as exc:  # the backend broke (worker killed, scheduler lost)
            outcome.stopped = f"{type(exc).__name__}: {' '.join(str(exc).split())}"
        _aggregate(sweep, store, out, outcome)
        write_manifest(out, WHAT)
    finally:
        if lock is not None:
            lock.close()
    if not outcome.unfinished:
        say(results_line(out))
    return outcome


def _aggregate(sweep: Sweep, store: ResultStore, out: Path, outcome: Outcome) -> None:
    rows, failures, unfinished = [], [], 0
    for task in sweep.tasks:
        result = store.get(task.key)
        if result is None:
            unfinished += 1
        elif result["status"] == "failed":
            failures.append({"task": task.key, **task.overrides, "error": result["error"]})
        else:
            for position, row in enumerate(result["rows"]):
                rows.append(read_row(row).with_extra(**task.overrides, task=task.key,
                                                     **{POSITION: position}))
    outcome.rows, outcome.failures, outcome.unfinished = rows, failures, unfinished
    if unfinished:
        return  # no table from a partial grid; the next run completes it
    swept = list(sweep.grid)
    # the store holds no NaN; table.json stays JSON
    text = json.dumps({"rows": [row.to_json() for row in rows], "failures": failures,
                       "swept": swept}, indent=1, allow_nan=False)
    atomic_write(out / "table.json", text)
    atomic_write(out / "table.md", markdown(rows, swept, failures))
    atomic_write(out / "table.csv", table_md.to_csv(rows, swept))
    if rows:
        from experiments import plots
        from experiments.sweeps.figures import mae_vs_key_figure
        for key in swept:
            if key != "seed":
                fig = mae_vs_key_figure(rows, swept, key)
                plots.save(fig, out / "figures" / f"mae_vs_{slug(key)}.png")


def markdown(rows: list[Row], swept: list[str], failures: list[dict]) -> str:
    """``table.md`` of a sweep: with ``seed`` swept, the mean ± std over the seeds first, then
    the rows of every task (and the failures)."""
    every = table_md.to_markdown(rows, swept)
    if failures:
        every += f"\n{len(failures)} failed task(s):\n\n" + "".join(
            "- " + ", ".join(f"{k}={table_md.fmt(f[k])}" for k in swept) + f": {f['error']}\n"
            for f in failures)
    if "seed" not in swept or not rows:
        return every
    others = [k for k in swept if k != "seed"]
    n = len({row.value("seed") for row in rows})
    return (f"## Mean ± std over the {n} swept seeds\n\n"
            + table_md.to_markdown(over_seeds(rows, swept), others)
            + "\n## Every task (one seed each; ± is over a row's own training seeds)\n\n"
            + every)

