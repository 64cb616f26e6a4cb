"""The checks of a model file on load (``lip.json``, a PGNN's ``.json`` sidecar and ``.pt``,
``diagnosis.json``): every consumer (``diagnose --model``, ``export-ff``, the Python API) reads
through them, so a file that cannot be a model is refused in one line before any use.

- strict JSON (the ``json`` module, not YAML 1.1: ``1e-05`` is a number), without ``NaN`` or
  ``Infinity``, a regular file of at most ``MAX_BYTES``, nested at most as deep as Python parses;
- parameters are finite numbers (``true`` is not 1 kg), scalings positive, sample times
  plausible (``MIN_TS`` .. ``MAX_TS``).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from clm_sim.errors import UserError

MAX_BYTES = 64 * 2 ** 20  # a model's JSON is kilobytes (a PGNN's history: a few megabytes)
MIN_TS = 1e-7  # s: as clm_sim.records.checks.MIN_TS: no servo samples faster than 10 MHz
MAX_TS = 0.1  # s: no servo samples slower than 10 Hz


def _no_constant(name: str):
    raise ValueError(f"{name} is not a number in strict JSON")


def _finite_int(text: str) -> int:
    """A JSON integer, refused where no float holds it (a 400-digit integer is valid JSON, and
    every parameter is used as a float)."""
    value = int(text)
    try:
        float(value)
    except OverflowError:
        raise ValueError(f"the integer {text[:12]}... ({len(text)} digits) is beyond the range "
                         f"of a number (about 1.8e308)") from None
    return value


def regular_file(path, what: str = "file") -> Path:
    """``path`` if it is a regular file (not a folder, a device, a FIFO); else one line."""
    path = Path(path)
    if not path.exists():
        raise UserError(f"{path}: {what} not found")
    if not path.is_file():
        raise UserError(f"{path}: not a regular file (a folder, device or pipe is no {what})")
    return path


def read_json(path, what: str = "model file") -> dict:
    """The JSON object in ``path``, strictly: one line for anything else."""
    path = regular_file(path, what)
    try:
        if path.stat().st_size > MAX_BYTES:
            raise UserError(f"{path}: {path.stat().st_size} bytes; a {what} has at most "
                            f"{MAX_BYTES} bytes")
        data = json.loads(path.read_text(encoding="utf-8"), parse_constant=_no_constant,
                          parse_int=_finite_int)
    except UserError:
        raise
    except RecursionError:
        raise UserError(f"{path}: not a {what}: JSON nested too deeply") from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise UserError(f"{path}: not a {what}: invalid JSON ({exc})") from None
    if not isinstance(data, dict):
        raise UserError(f"{path}: not a {what}: expected a JSON object, got "
                        f"{type(data).__name__}")
    return data


def number(value, key: str, *, positive: bool = False) -> float:
    """``value`` as a finite float (``positive``: > 0); booleans, text and null refused."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise UserError(f"{key}: expected a number, got {json.dumps(value)[:60]}")
    try:
        value = float(value)
    except OverflowError:
        raise UserError(f"{key}: expected a number, got an integer of {len(str(value))} "
                        f"digits, beyond the range of a number") from None
    if not math.isfinite(value):
        raise UserError(f"{key}: expected a finite number, got {value}")
    if positive and not value > 0:
        raise UserError(f"{key}: expected a positive number, got {value:g}")
    return value


def mapping(value, key: str) -> dict:
    """``value`` if it is a JSON object (``{}`` for null)."""
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise UserError(f"{key}: expected an object, got {type(value).__name__}")
    return value


def sample_time(value, key: str = "ts") -> float | None:
    """A stored sample time (s): None where the file has none, else in ``MIN_TS`` .. ``MAX_TS``."""
    if value is None:
        return None
    ts = number(value, key, positive=True)
    if not MIN_TS <= ts <= MAX_TS:
        raise UserError(f"{key}: {ts:g} s is not a servo sample time ({MIN_TS:g} .. "
                        f"{MAX_TS:g} s)")
    return ts
