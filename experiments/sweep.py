"""Sweeps: a grid over config keys, one independent task per grid point, one table at the end.

A sweep config is an experiment config with a ``sweep:`` section::

    sweep:
      grid:
        plant.encoder_resolution: {logspace: [1.0e-9, 5.0e-6, 9]}   # start, stop (m), points
        feedforwards[2].lambda: [0.0, 0.01, 1.0]
        seed: [1, 2, 3, 4, 5]
      max_tasks: 10000            # refuse larger grids (default MAX_TASKS)

Keys are paths into the *resolved* config (every default filled in), so any key can be swept,
including ones the file does not mention (``plant.effects[0].amplitude``). Every grid point is
built and checked strictly before anything runs; a bad key or value is one ``UserError``.

Tasks are stored by :mod:`experiments.store` under a hash of their resolved config and the code
version, so a re-run (after a crash, ``SIGKILL`` included) computes only unfinished tasks. A task
that fails (diverged loop, unstable PID design, ...) is stored with its error and the others go
on. The output folder holds ``tasks/`` (one JSON per task), ``table.json`` (the shared schema,
each row extended with the swept keys and its task key, plus a ``failures`` list), ``table.md``,
``table.csv`` and ``figures/mae_vs_<key>.png`` (MAE against each swept key, mean and spread over
seeds).
"""

from __future__ import annotations

import copy
import csv
import io
import itertools
import json
import math
import os
import re
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from clm_sim.errors import UserError
from clm_sim.plant import THETA_NAMES
from clm_sim.schema import build, load_yaml
from experiments.config import ExperimentConfig, resolved
from experiments.store import ResultStore, atomic_write_bytes, code_version, task_key

MAX_TASKS = 10_000
_SWEEP_KEYS = ("grid", "max_tasks")
_PIECE = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)((?:\[\d+\])*)")


@dataclass(frozen=True)
class Task:
    """One grid point: its overrides ``{path: value}``, resolved config and storage key."""

    index: int
    overrides: dict
    config: dict
    key: str


@dataclass(frozen=True)
class Sweep:
    """A checked sweep: the base config (resolved), the grid and its tasks in grid order."""

    path: Path
    base: dict
    grid: dict[str, list]
    tasks: tuple[Task, ...]
    code_version: str


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


# ----------------------------------------------------------------------------- grid and tasks

def parse_path(text: str) -> list:
    """``"plant.effects[0].amplitude"`` -> ``["plant", "effects", 0, "amplitude"]``."""
    parts: list = []
    if not isinstance(text, str) or not text:
        raise ValueError("expected a key path such as plant.encoder_resolution")
    for piece in text.split("."):
        m = _PIECE.fullmatch(piece)
        if not m:
            raise ValueError(f"malformed key path {text!r} (expected names joined by dots, "
                             f"list items as [index])")
        parts.append(m.group(1))
        parts.extend(int(i) for i in re.findall(r"\[(\d+)\]", m.group(2)))
    return parts


def set_path(data: dict, parts: list, value) -> None:
    """Set ``value`` at ``parts`` inside ``data`` (in place); the path must already exist."""
    node = data
    for depth, part in enumerate(parts):
        last = depth == len(parts) - 1
        where = _join(parts[:depth]) or "the config"
        if isinstance(part, int):
            if not isinstance(node, list):
                raise ValueError(f"{where} is not a list")
            if part >= len(node):
                raise ValueError(f"index {part} out of range: {where} has {len(node)} entries")
        else:
            if not isinstance(node, dict):
                raise ValueError(f"{where} is not a mapping")
            if part not in node:
                raise ValueError(f"unknown key {part!r} in {where}; known keys: "
                                 f"{', '.join(map(str, node))}")
        if last:
            node[part] = value
        else:
            node = node[part]


def _join(parts: list) -> str:
    out = ""
    for p in parts:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else p)
    return out


def _axis(values, where: str) -> list:
    """The values of one grid axis: a list, or ``{logspace|linspace: [start, stop, num]}``."""
    if isinstance(values, dict):
        if len(values) != 1 or next(iter(values)) not in ("logspace", "linspace"):
            raise UserError(f"{where}: expected a list of values or {{logspace: [start, stop, "
                            f"num]}} or {{linspace: [start, stop, num]}}, got {values!r}")
        kind, spec = next(iter(values.items()))
        ok = (isinstance(spec, list) and len(spec) == 3
              and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in spec)
              and isinstance(spec[2], int) and spec[2] >= 1
              and all(math.isfinite(v) for v in spec))
        if not ok or (kind == "logspace" and min(spec[:2]) <= 0):
            raise UserError(f"{where}.{kind}: expected [start, stop, num] with finite numbers"
                            f"{' > 0' if kind == 'logspace' else ''} and an integer num >= 1, "
                            f"got {spec!r}")
        start, stop, num = spec
        if num > MAX_TASKS:
            raise UserError(f"{where}.{kind}: {num} points exceed the limit of {MAX_TASKS}")
        grid = (np.geomspace(start, stop, num) if kind == "logspace"
                else np.linspace(start, stop, num))
        values = [float(f"{v:.12g}") for v in grid]
        if kind == "linspace" and all(isinstance(v, int) for v in spec[:2]) \
                and all(v.is_integer() for v in values):
            return [int(v) for v in values]  # an integer axis (seeds, neurons) stays integer
        return values
    if not isinstance(values, list) or not values:
        raise UserError(f"{where}: expected a non-empty list of values, got {values!r}")
    seen = []
    for v in values:
        if v in seen:
            raise UserError(f"{where}: value {v!r} appears twice")
        seen.append(v)
    return list(values)


def _axis_size(values) -> int:
    """Number of values an axis declares, without expanding it (1 if malformed: checked later)."""
    if isinstance(values, list):
        return len(values)
    if isinstance(values, dict) and len(values) == 1:
        spec = next(iter(values.values()))
        if isinstance(spec, list) and len(spec) == 3 and isinstance(spec[2], int):
            return max(spec[2], 1)
    return 1


def _point_error(path: Path, overrides: dict, exc: Exception) -> UserError:
    point = ", ".join(f"{k}={v!r}" for k, v in overrides.items())
    msg = str(exc).removeprefix("config.").removeprefix("config: ")
    return UserError(f"{path}: sweep point {point}: {msg}")


def _check(base: dict, overrides: dict, parts: dict) -> dict:
    """Apply ``overrides`` to a copy of ``base``, build and preflight it; the resolved config."""
    from experiments.runner import preflight

    data = copy.deepcopy(base)
    for key, value in overrides.items():
        set_path(data, parts[key], value)
    config = build(ExperimentConfig, data, "config")
    preflight(config)
    return resolved(config)


def load_sweep(path, *, max_tasks: int | None = None) -> Sweep:
    """Read a (sweep) config and check every grid point; nothing runs, nothing is written.

    A config without a ``sweep:`` section is a sweep of one task. Raises ``UserError`` naming
    the file and the key for a malformed section, an unknown key path, a value the config
    refuses, or a grid larger than ``max_tasks`` (the section's ``max_tasks``, else MAX_TASKS).
    """
    from experiments.runner import preflight

    path = Path(path)
    data = load_yaml(path)
    section = data.pop("sweep", None) or {}
    if not isinstance(section, dict):
        raise UserError(f"{path}: sweep: expected a mapping with 'grid', got {section!r}")
    for key in section:
        if key not in _SWEEP_KEYS:
            raise UserError(f"{path}: sweep.{key}: unknown key; known keys: "
                            f"{', '.join(_SWEEP_KEYS)}")
    limit = section.get("max_tasks", MAX_TASKS) if max_tasks is None else max_tasks
    if isinstance(limit, bool) or not isinstance(limit, int) or limit < 1:
        raise UserError(f"{path}: sweep.max_tasks: expected an integer >= 1, got {limit!r}")
    raw_grid = section.get("grid", {})
    if not isinstance(raw_grid, dict):
        raise UserError(f"{path}: sweep.grid: expected a mapping of key paths to value lists, "
                        f"got {raw_grid!r}")
    # Size first, from the axis lengths alone: a huge grid is refused before it is expanded.
    n_tasks = math.prod(_axis_size(v) for v in raw_grid.values())
    if n_tasks > limit:
        raise UserError(f"{path}: sweep.grid: {n_tasks} tasks exceed the limit of {limit} "
                        f"(raise sweep.max_tasks if you mean it)")
    grid, parts = {}, {}
    for key, values in raw_grid.items():
        where = f"sweep.grid.{key}"
        try:
            parts[key] = parse_path(key)
        except ValueError as exc:
            raise UserError(f"{path}: {where}: {exc}") from None
        grid[key] = _axis(values, f"{path}: {where}")
    try:
        base_config = build(ExperimentConfig, data, "config")
        preflight(base_config)
    except UserError as exc:
        raise UserError(f"{path}: {str(exc).removeprefix('config.').removeprefix('config: ')}") \
            from None
    base = resolved(base_config)
    # Each axis alone first, so that a bad key or value is named without the rest of the point.
    for key, values in grid.items():
        for value in values:
            try:
                _check(base, {key: value}, parts)
            except ValueError as exc:
                raise UserError(f"{path}: sweep.grid.{key}: {exc}") from None
            except UserError as exc:
                raise _point_error(path, {key: value}, exc) from None
    version = code_version()
    tasks = []
    for i, combo in enumerate(itertools.product(*grid.values())):
        overrides = dict(zip(grid, combo))
        try:
            config = _check(base, overrides, parts)
        except (UserError, ValueError) as exc:
            raise _point_error(path, overrides, exc) from None
        tasks.append(Task(i, overrides, config, task_key(config, version)))
    return Sweep(path, base, grid, tuple(tasks), version)


# ----------------------------------------------------------------------------- one task

def execute(config_plain: dict) -> dict:
    """Run one task in a worker: ``{"status": "ok", "rows"}`` or ``{"status": "failed",
    "error"}``. Never raises for the task's own failure, so one bad point cannot stop a sweep."""
    from experiments.runner import run_task

    start = time.perf_counter()
    try:
        config = build(ExperimentConfig, config_plain, "config")
        if any(spec.kind == "pgnn" for spec in config.feedforwards):
            import torch
            torch.set_num_threads(1)  # one core per task; the sweep runs tasks in parallel
        rows = run_task(config)
        json.dumps(rows, allow_nan=False)  # a NaN or inf in the results is a failure
        return {"status": "ok", "rows": rows, "elapsed_s": time.perf_counter() - start}
    except Exception as exc:  # recorded, not raised: the sweep goes on with the other tasks
        text = " ".join(str(exc).split()) or type(exc).__name__
        return {"status": "failed", "error": f"{type(exc).__name__}: {text}",
                "elapsed_s": time.perf_counter() - start}


# ----------------------------------------------------------------------------- running

def check_output(out: Path) -> None:
    """Refuse an output folder that exists and is not a sweep's (before anything is written)."""
    out = Path(out)
    # A sweep killed right after it started may have left only its lock and task folder.
    mine = {"sweep.resolved.yaml", "tasks"}
    if out.exists() and (not out.is_dir() or not (
            (out / "sweep.resolved.yaml").exists()
            or all(p.name.startswith(".") or p.name in mine for p in out.iterdir()))):
        raise UserError(f"{out}: output folder exists and does not hold clm-sim sweep results; "
                        f"choose another --out")


def _lock(out: Path):
    try:
        import fcntl
    except ImportError:  # Windows: no advisory lock
        return None
    fh = open(out / ".lock", "w")
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
    from experiments.backends import BACKENDS

    out = Path(out)
    check_output(out)
    if workers is None:
        workers = (len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
                   else os.cpu_count() or 1)
    if workers < 1:
        raise UserError(f"--workers: expected an integer >= 1, got {workers}")
    start = time.perf_counter()

    def say(msg):
        if not quiet:
            print(f"[{time.perf_counter() - start:7.1f} s] {msg}", file=sys.stderr, flush=True)

    out.mkdir(parents=True, exist_ok=True)
    lock = _lock(out)
    try:
        store = ResultStore(out / "tasks").open()
        atomic_write_bytes(out / "sweep.resolved.yaml", yaml.safe_dump(
            {"base": sweep.base, "grid": sweep.grid, "code_version": sweep.code_version},
            sort_keys=False).encode())
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
    finally:
        if lock is not None:
            lock.close()
    if not outcome.unfinished:
        say(f"results in {out}/ (table.md, table.json, figures/)")
    return outcome


# ----------------------------------------------------------------------------- aggregation

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
                rows.append({**row, **task.overrides, "task": task.key, "row": position})
    outcome.rows, outcome.failures, outcome.unfinished = rows, failures, unfinished
    if unfinished:
        return  # no table from a partial grid; the next run completes it
    swept = list(sweep.grid)
    text = json.dumps({"rows": rows, "failures": failures, "swept": swept}, indent=1)
    atomic_write_bytes(out / "table.json", text.encode())
    atomic_write_bytes(out / "table.md", to_markdown(rows, swept, failures).encode())
    atomic_write_bytes(out / "table.csv", to_csv(rows, swept).encode())
    if rows:
        (out / "figures").mkdir(exist_ok=True)
        for key in swept:
            if key != "seed":
                plot_mae(rows, swept, key, out / "figures" / f"mae_vs_{_slug(key)}.png")


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9]+", "_", text).strip("_")


def _fmt(value) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def to_markdown(rows: list[dict], swept: list[str], failures: list[dict]) -> str:
    """One line per task and feedforward: swept values, MAE (µm) per reference, theta_phy."""
    refs = list(rows[0]["mae"]) if rows else []
    head = swept + ["feedforward", "seeds"] + [f"MAE {r} [µm]" for r in refs] + list(THETA_NAMES)
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in rows:
        th = row["theta_phy"]
        mae = [f"{row['mae'][r]['mean'] * 1e6:.3f}" + (f" ± {row['mae'][r]['std'] * 1e6:.3f}"
                                                         if row["mae"][r]["std"] else "")
               for r in refs]
        cells = ([_fmt(row[k]) for k in swept] + [row["label"], str(row["n_seeds"])] + mae
                 + ([f"{th[k]:.4g}" for k in THETA_NAMES] if th else ["–"] * 4))
        lines.append("| " + " | ".join(cells) + " |")
    text = "\n".join(lines) + "\n"
    if failures:
        text += f"\n{len(failures)} failed task(s):\n\n" + "".join(
            "- " + ", ".join(f"{k}={_fmt(f[k])}" for k in swept) + f": {f['error']}\n"
            for f in failures)
    return text


def to_csv(rows: list[dict], swept: list[str]) -> str:
    refs = list(rows[0]["mae"]) if rows else []
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(swept + ["label", "kind", "training", "lambda", "hidden", "n_seeds"]
               + [f"mae_{r}_{s}_m" for r in refs for s in ("mean", "std")]
               + [f"theta_{k}" for k in THETA_NAMES] + ["task"])
    for row in rows:
        th = row["theta_phy"] or {}
        w.writerow([row[k] for k in swept] + [row["label"], row["kind"], row["training"] or "",
                                              "" if row["lambda"] is None else row["lambda"],
                                              row["hidden"] or "", row["n_seeds"]]
                   + [f"{row['mae'][r][s]:.6e}" for r in refs for s in ("mean", "std")]
                   + [f"{th[k]:.6g}" if th else "" for k in THETA_NAMES] + [row["task"]])
    return buf.getvalue()


def _series_labels(rows: list[dict]) -> dict[int, str]:
    """A label per feedforward position that does not change along the sweep."""
    by_pos: dict[int, set] = {}
    for row in rows:
        by_pos.setdefault(row["row"], set()).add(row["label"])
    labels = {}
    for pos, names in by_pos.items():
        if len(names) == 1:
            labels[pos] = next(iter(names))
        else:
            row = next(r for r in rows if r["row"] == pos)
            labels[pos] = {"none": "feedback only", "lip": "LIP"}.get(
                row["kind"], f"PGNN {row['training']}")
    return labels


def _applies(key: str, position: int) -> bool:
    """Whether swept ``key`` can change the row at feedforward ``position`` (a key of another
    feedforward, ``feedforwards[j]...``, cannot)."""
    m = re.match(r"feedforwards\[(\d+)\]", key)
    return m is None or int(m.group(1)) == position


def series(rows: list[dict], swept: list[str], x: str) -> dict:
    """``{(label, ref): {x_value: (mean, spread, n)}}``: MAE (m) per series and x, with the
    spread over the swept seeds (sample std), or the rows' own std over training seeds when
    ``seed`` is not swept. Other swept keys split the series. A row that ``x`` cannot change
    (the LIP when a PGNN's lambda is swept) is one flat series: the same statistics at every x;
    copies of it from grid points that differ only in another feedforward's keys count once."""
    labels = _series_labels(rows)
    xs = list(dict.fromkeys(row[x] for row in rows))
    groups: dict = {}
    seen = set()
    for row in rows:
        pos = row["row"]
        applies = [k for k in swept if _applies(k, pos)]
        ident = (pos, tuple(row[k] for k in applies))
        if ident in seen:
            continue
        seen.add(ident)
        name = labels[pos] + "".join(f", {k.split('.')[-1]}={_fmt(row[k])}"
                                     for k in applies if k not in (x, "seed"))
        for ref, stat in row["mae"].items():
            by_x = groups.setdefault((name, ref), {})
            for xv in ([row[x]] if x in applies else xs):
                by_x.setdefault(xv, []).append(stat)
    out = {}
    for key, by_x in groups.items():
        out[key] = {}
        for xv, stats in by_x.items():
            means = np.array([s["mean"] for s in stats])
            spread = float(means.std(ddof=1)) if len(means) > 1 else float(stats[0]["std"])
            out[key][xv] = (float(means.mean()), spread, len(means))
    return out


def plot_mae(rows: list[dict], swept: list[str], x: str, path: Path) -> None:
    """MAE (µm) against swept key ``x``, one panel per reference, mean ± spread over seeds."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter

    data = series(rows, swept, x)
    refs = sorted({ref for _, ref in data})
    xs = [row[x] for row in rows]
    numeric = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in xs)
    cats = list(dict.fromkeys(map(str, xs))) if not numeric else None
    fig, axes = plt.subplots(1, len(refs), figsize=(5.2 * len(refs), 4.0), squeeze=False)
    for ax, ref in zip(axes[0], refs):
        means = [m for (_, r), by_x in data.items() if r == ref for m, _, _ in by_x.values()]
        for (name, r), by_x in data.items():
            if r != ref:
                continue
            keys = sorted(by_x) if numeric else sorted(by_x, key=lambda v: cats.index(str(v)))
            pos = np.array(keys, float) if numeric else np.array([cats.index(str(k))
                                                                  for k in keys], float)
            mean = np.array([by_x[k][0] for k in keys]) * 1e6
            spread = np.array([by_x[k][1] for k in keys]) * 1e6
            line, = ax.plot(pos, mean, marker="o", ms=3, lw=1.2, label=name)
            ax.fill_between(pos, np.maximum(mean - spread, 1e-6), mean + spread,
                            color=line.get_color(), alpha=0.2, lw=0)
        if numeric:
            vals = np.array(sorted(set(xs)), float)
            positive = vals[vals > 0]
            if len(positive) and positive.max() / positive.min() > 20:
                if (vals <= 0).any():
                    ax.set_xscale("symlog", linthresh=positive.min())
                else:
                    ax.set_xscale("log")
        else:
            ax.set_xticks(range(len(cats)), cats)
        if min(means) > 0 and max(means) / min(means) > 20:
            ax.set_yscale("log")
            plain = FuncFormatter(lambda v, _: f"{v:g}")  # 0.2, 0.4, 1, 2 rather than 2x10^-1
            ax.yaxis.set_major_formatter(plain)
            ax.yaxis.set_minor_formatter(FuncFormatter(
                lambda v, _: f"{v:g}" if f"{v:.0e}"[0] in "25" else ""))
        ax.set_xlabel(x)
        ax.set_ylabel(f"MAE on {ref} [µm]")
        ax.grid(alpha=0.3, which="both")
        ax.set_title(f"MAE on {ref} vs {x.split('.')[-1]}")
    axes[0][-1].legend(fontsize=7)
    fig.tight_layout()
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}.png")
    fig.savefig(tmp, dpi=90)
    plt.close(fig)
    os.replace(tmp, path)
