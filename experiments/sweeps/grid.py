"""A sweep's grid: key paths into the resolved config, the values of each axis, and the tasks.

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
"""

from __future__ import annotations

import copy
import itertools
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from clm_sim.errors import UserError
from clm_sim.schema import build, load_yaml
from experiments.config import ExperimentConfig, in_file, resolved
from experiments.runner import preflight
from experiments.sweeps.store import code_version, task_key

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
    return in_file(path, exc, f"sweep point {point}")


def _check(base: dict, overrides: dict, parts: dict) -> dict:
    """Apply ``overrides`` to a copy of ``base``, build and preflight it; the resolved config."""
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
    # A run on measured records scores force errors, not the tracking a sweep's table holds:
    # refused in the base config and as a swept key alike.
    on_records = ["data"] if "data" in data else [
        f"sweep.grid.{key}" for key in grid if parts[key][0] == "data"]
    if on_records:
        raise UserError(f"{path}: {on_records[0]}: a sweep runs the simulated testbed; a config "
                        f"on measured records (data:) is run one at a time with 'clm-sim run'")
    try:
        base_config = build(ExperimentConfig, data, "config")
        preflight(base_config)
    except UserError as exc:
        raise in_file(path, exc) from None
    base = resolved(base_config)
    # Each axis alone first, so that a bad key or value is named without the rest of the point.
    for key, values in grid.items():
        for value in values:
            try:
                _check(base, {key: value}, parts)
            except UserError as exc:  # before ValueError: a UserError is one
                raise _point_error(path, {key: value}, exc) from None
            except ValueError as exc:
                raise UserError(f"{path}: sweep.grid.{key}: {exc}") from None
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
