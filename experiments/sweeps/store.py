"""A content-addressed, crash-safe store of sweep task results.

Each task's result is one JSON file ``<root>/<key>.json`` where ``key`` hashes the task's resolved
config and the code version, so a re-run finds finished tasks and a code change recomputes them.
Files are written by :func:`clm_sim.outdir.atomic_write`: a reader, or a sweep resumed after
``SIGKILL``, sees either the whole file or none of it. Temporary files are dot-files and never
count as results.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import stat
from pathlib import Path

from clm_sim import __version__
from clm_sim.errors import UserError
from clm_sim.outdir import atomic_write

# The repository root (this file is experiments/sweeps/store.py).
_PACKAGE_ROOT = Path(__file__).resolve().parents[2]
# The sources a task result depends on: physics, controllers, and the runner chain that turns a
# config into table rows (testbed, fits on records, identifiability). Sweep, CLI, figure and
# diagnosis code do not change a task's numbers.
_RESULT_SOURCES = ("clm_sim", "controllers", "experiments/config.py", "experiments/runner.py",
                   "experiments/table.py", "experiments/testbed.py", "experiments/records/fit.py",
                   "experiments/studies/profiles/identifiability.py")
_NOT_RESULT_SOURCES = ("experiments/diagnosis",)


def result_sources() -> list[Path]:
    """The files :func:`code_version` hashes, in the order it hashes them."""
    files = []
    for entry in _RESULT_SOURCES:
        path = _PACKAGE_ROOT / entry
        if not path.exists():
            raise RuntimeError(f"code_version: {entry} is not in {_PACKAGE_ROOT} (moved? update "
                               f"_RESULT_SOURCES)")
        for f in sorted(path.rglob("*.py")) if path.is_dir() else [path]:
            if not f.relative_to(_PACKAGE_ROOT).as_posix().startswith(_NOT_RESULT_SOURCES):
                files.append(f)
    return files


def code_version() -> str:
    """``<clm_sim.__version__>+<hash of the sources that compute task results>``, read from the
    files now (an edited source gives a new version, so its tasks are recomputed)."""
    digest = hashlib.sha256()
    for f in result_sources():
        digest.update(f.relative_to(_PACKAGE_ROOT).as_posix().encode() + b"\0")
        digest.update(f.read_bytes() + b"\0")
    return f"{__version__}+{digest.hexdigest()[:12]}"


def task_key(resolved_config: dict, version: str | None = None) -> str:
    """Hash of a resolved config (plain data) and the code version: the task's storage key."""
    text = json.dumps({"config": resolved_config, "code": version or code_version()},
                      sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()[:24]


class ResultStore:
    """Task results under ``root``, one JSON document per key."""

    def __init__(self, root: Path):
        self.root = Path(root)
        self.on_invalid = None  # called with (path, reason) for a task file that is refused

    def open(self) -> "ResultStore":
        """Create the folder and remove temporary files left by a killed writer."""
        self.root.mkdir(parents=True, exist_ok=True)
        for tmp in self.root.glob(".*.tmp*"):
            tmp.unlink(missing_ok=True)
        return self

    def path(self, key: str) -> Path:
        return self.root / f"{key}.json"

    def get(self, key: str) -> dict | None:
        """The stored result of ``key``, or ``None`` if the task has not finished or its file
        is not a result of this task (not strict JSON, NaN or inf, another task's key or config,
        a link): such a file is said once (``on_invalid``), removed, and the task recomputed."""
        path = self.path(key)
        try:
            result = json.loads(_read_regular(path), parse_constant=_no_constant)
            why = _invalid(result, key)
        except FileNotFoundError:
            return None
        except (OSError, UnicodeDecodeError, ValueError, RecursionError) as exc:
            why = f"unreadable ({type(exc).__name__}: {' '.join(str(exc).split())[:120]})"
        if why is None:
            return result
        if self.on_invalid is not None:
            self.on_invalid(path, why)
        try:
            path.unlink(missing_ok=True)
        except OSError:  # a folder in its place, say: the user's to remove
            raise UserError(f"{path}: {why}; remove it to resume the sweep") from None
        return None

    def put(self, key: str, result: dict) -> None:
        atomic_write(self.path(key), json.dumps(result, indent=1, allow_nan=False))


# A task result is a few kB per row; a file far beyond any table is not one (and is not read).
MAX_TASK_BYTES = 64 * 2 ** 20


def _read_regular(path: Path) -> str:
    """The text of ``path`` if it is a regular file of at most :data:`MAX_TASK_BYTES`, opened
    without following a link and without blocking (a FIFO or a device put in its place would
    hang the read); ``FileNotFoundError`` if absent, ``ValueError`` for anything else."""
    flags = os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0)
    try:
        fd = os.open(path, flags)
    except OSError as exc:
        if isinstance(exc, FileNotFoundError):
            raise
        if path.is_symlink():
            raise ValueError("a symbolic link, not a task result") from None
        raise
    with os.fdopen(fd, "rb") as fh:
        info = os.fstat(fh.fileno())
        if not stat.S_ISREG(info.st_mode):
            raise ValueError("not a regular file")
        if info.st_size > MAX_TASK_BYTES:
            raise ValueError(f"{info.st_size} bytes, above the {MAX_TASK_BYTES} of a task result")
        return fh.read(MAX_TASK_BYTES + 1).decode("utf-8")


def _no_constant(name: str):
    raise ValueError(f"{name} is not a number in strict JSON")


def _invalid(result, key: str) -> str | None:
    """Why ``result`` is not the stored result of task ``key`` (None: it is)."""
    if not isinstance(result, dict):
        return "not a task result (a JSON object)"
    if result.get("key") != key:
        return f"holds the result of task {str(result.get('key'))[:30]!r}, not of {key}"
    try:
        if task_key(result.get("config"), result.get("code_version")) != key:
            return "its config does not hash to its key (edited or swapped)"
    except (TypeError, ValueError):
        return "its config is not plain data"
    if result.get("status") == "ok":
        return _invalid_rows(result.get("rows"), result.get("config"))
    if result.get("status") == "failed":
        return None if isinstance(result.get("error"), str) else "a failure without its error"
    return f"status {str(result.get('status'))[:30]!r} is neither ok nor failed"


# The metrics of a row (errors and their spreads): non-negative finite numbers wherever given.
_METRICS = ("mae", "rms", "max", "mae_per_seed", "force_rms", "force_rms_per_seed")


def _invalid_rows(rows, config) -> str | None:
    """Why ``rows`` are not the table rows of a task with ``config`` (None: they are): one row
    (an object with a label and at least one error metric) per feedforward of the config, every
    error a non-negative finite number."""
    if not isinstance(rows, list) or not rows:
        return "no rows"
    wanted = config.get("feedforwards") if isinstance(config, dict) else None
    if isinstance(wanted, list) and len(rows) != len(wanted):
        return f"{len(rows)} rows for the task's {len(wanted)} feedforwards"
    for i, row in enumerate(rows):
        if not isinstance(row, dict) or not isinstance(row.get("label"), str):
            return f"row {i} is not a table row"
        if not any(key in row for key in ("mae", "force_rms")):
            return f"row {i} has no error metric"
        for key in _METRICS:
            bad = _bad_metric(row.get(key))
            if bad is not None:
                return f"row {i} {key}: {bad!r} is not a non-negative finite number"
    return None


def _bad_metric(value):
    """The first value under ``value`` (nested objects and lists) that is not a non-negative
    finite number (``None`` stands for a statistic with no data), else ``None``."""
    if value is None:
        return None
    if isinstance(value, (dict, list)):
        for item in value.values() if isinstance(value, dict) else value:
            bad = _bad_metric(item)
            if bad is not None:
                return bad
        return None
    if isinstance(value, (int, float)) and not isinstance(value, bool) \
            and math.isfinite(value) and value >= 0:
        return None
    return value
