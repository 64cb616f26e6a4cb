"""The checks of a record's signals: numbers (not text, cells or complex values), a unit
scale that keeps their squares finite, and time stamps that are strictly increasing and
uniform; the orders of magnitude SI data cannot have."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from clm_sim.errors import UserError

MAX_TS = 0.01  # s: a servo record sampled slower than 100 Hz has its time stamps in ms
MIN_TS = 1e-7  # s: no servo samples faster than 10 MHz; such time stamps are in other units
UNIFORM_RTOL = 1e-3  # a step may differ from the mean step by this share, beyond the rounding
COARSE_STAMPS = 0.01  # stamps whose type's spacing exceeds this share of a step cannot show it
MAX_POSITION_M = 10.0  # m: longer than any linear-motor stroke; larger values are in mm or counts
MAX_FORCE_N = 1e6  # N: 50 times the peak force of the largest linear motors; larger is not N
# A scaled signal's peak must lie here (about 1.5e-154 to 1.3e154) so its squares are finite and
# not zero: a scale outside gives a fit of NaN, not a refusal.
SQUARE_RANGE = (float(np.sqrt(np.finfo(float).tiny)), float(np.sqrt(np.finfo(float).max)))


_KINDS = {"U": "text", "S": "bytes", "O": "cells or objects", "V": "a struct or record",
          "M": "dates", "m": "time spans"}


def numbers(value, path: Path, key: str) -> np.ndarray:
    """``value`` as a float64 array, or one line saying what the variable ``key`` holds
    instead (text, a MATLAB cell, struct or sparse matrix, complex numbers)."""
    if not isinstance(value, np.ndarray):  # scipy.sparse from a MATLAB sparse matrix
        raise UserError(f"{path}: variable {key!r} is {type(value).__name__}, expected a "
                        f"dense numeric array (store it with full(...) in MATLAB)")
    kind = value.dtype.kind
    if kind in _KINDS:
        raise UserError(f"{path}: variable {key!r} holds {_KINDS[kind]}, expected numbers")
    if kind == "c":
        if np.any(value.imag != 0):
            raise UserError(f"{path}: variable {key!r} is complex; expected real numbers")
        value = value.real
    return np.asarray(value, dtype=np.float64)


def scaled(value: np.ndarray, factor: float, path: Path, name: str) -> np.ndarray:
    """``value * factor``, refused in one line where the factor takes the signal out of the
    range in which its squares (every fit's residual and norm) are finite and non-zero."""
    with np.errstate(over="ignore", under="ignore"):
        scaled = value * factor
    finite = np.isfinite(value)
    peak = float(np.max(np.abs(scaled[finite]), initial=0.0))
    if not np.isfinite(scaled[finite]).all() or peak > SQUARE_RANGE[1]:
        raise UserError(f"{path}: scale for {name!r} is {factor:g}; it takes {name} to "
                        f"{peak:.3g}, beyond float64 once squared; expected a unit factor "
                        f"(e.g. 35.15 for V to N, 0.001 for mm to m)")
    if np.any(value[finite]) and peak < SQUARE_RANGE[0]:
        raise UserError(f"{path}: scale for {name!r} is {factor:g}; it shrinks {name} to "
                        f"{peak:.3g} at most, whose squares underflow float64 to 0; expected a "
                        f"unit factor (e.g. 35.15 for V to N, 0.001 for mm to m)")
    return scaled


def _coarse_stamps(t: np.ndarray, ts: float, resolution: float, dtype) -> str:
    """Why time stamps ``t`` (s, step ``ts``) cannot resolve their step better than
    ``resolution`` (s), and the cure: float64, and stamps from the first sample."""
    top = float(np.max(np.abs(t)))
    cures = [] if dtype == np.float64 or dtype.kind not in "fc" else ["as float64"]
    if abs(float(t[0])) > float(t[-1] - t[0]):  # an offset (Unix-epoch seconds) costs digits
        cures.append("from the first sample (t - t[0])")
    return (f"its {dtype} time stamps reach {top:.3g} s, where they are {resolution:.2g} s apart "
            f"({100 * resolution / ts:.2g} % of the {ts:.3g} s step)"
            + (f"; store t {' or '.join(cures)}" if cures else ""))


def uniform_step(t: np.ndarray, stamps: np.ndarray, where: str) -> float:
    """The sample time (s) of time stamps ``t`` (s, as scaled from ``stamps``, the column as
    stored), refused (``where``: the file and column) unless strictly increasing and uniform:
    every step within ``UNIFORM_RTOL`` of the mean step beyond the rounding of the stored type
    at that step (each stamp lies within half its spacing of the true time, so a step within
    one; integers are exact up to 2**53), plus float64's own rounding of the scaled times.
    Stamps whose spacing exceeds ``COARSE_STAMPS`` of a step cannot show it: refused, naming
    the type and the offset (float32 or Unix-epoch stamps are rounded, not uneven)."""
    top = float(np.max(np.abs(stamps)))
    scale = float(np.max(np.abs(t))) / top if top > 0 else 1.0

    def spacing(values: np.ndarray) -> np.ndarray:  # s, as scaled
        if stamps.dtype.kind in "fc":
            return np.spacing(np.abs(values).astype(stamps.dtype)).astype(np.float64) * scale
        magnitude = np.abs(values).astype(np.float64)
        return np.where(magnitude >= 2.0 ** 53, np.spacing(magnitude), 0.0) * scale

    dt = np.diff(t)
    resolution = float(spacing(np.array([top], dtype=stamps.dtype))[0])  # at the largest
    ts = (t[-1] - t[0]) / (len(t) - 1)
    if not (dt > 0).all():
        coarse = (f"; {_coarse_stamps(t, ts, resolution, stamps.dtype)}"
                  if ts > 0 and resolution > UNIFORM_RTOL * ts else "")
        raise UserError(f"{where} must be strictly increasing (row "
                        f"{int(np.argmax(dt <= 0)) + 1} is not{coarse})")
    coarse = _coarse_stamps(t, ts, resolution, stamps.dtype)
    ends = np.maximum(np.abs(stamps[:-1]), np.abs(stamps[1:]))
    rounding = spacing(ends) + np.spacing(np.maximum(np.abs(t[:-1]), np.abs(t[1:])))
    excess = np.abs(dt - ts) - (UNIFORM_RTOL * ts + rounding)
    if (excess > 0).any():
        # The type is to blame where the worst step's own rounding is of its size.
        k = int(np.argmax(excess))
        blame = (rounding[k] > UNIFORM_RTOL * ts
                 and abs(dt[k] - ts) <= UNIFORM_RTOL * ts + 4 * rounding[k])
        raise UserError(f"{where} is not uniformly sampled (steps from {dt.min():.6g} to "
                        f"{dt.max():.6g} s" + (f"; {coarse}" if blame else "") + ")")
    if resolution > COARSE_STAMPS * ts:
        raise UserError(f"{where} cannot show a uniform sampling: {coarse}")
    return float(ts)


def check_magnitudes(path: Path, signals: dict[str, np.ndarray], ts: float,
                     column: dict[str, str]) -> None:
    """Refuse orders of magnitude that SI data cannot have: a sample time ``ts`` (s) above
    ``MAX_TS`` (time stamps in ms) or below ``MIN_TS``, a position beyond ``MAX_POSITION_M``
    (mm), a force beyond ``MAX_FORCE_N``; ``column`` names each signal's column in the file."""
    if ts > MAX_TS:
        raise UserError(f"{path}: column {column['t']!r} steps by {ts:.6g} s, slower "
                        f"than a servo log ({1 / MAX_TS:g} Hz at least); are the time stamps "
                        f"in ms? (t must be in s)")
    if ts < MIN_TS:
        raise UserError(f"{path}: column {column['t']!r} steps by {ts:.6g} s, faster "
                        f"than any servo log ({1 / MIN_TS:g} Hz at most); t must be in s")
    for name in ("r", "y"):
        peak = float(np.max(np.abs(signals[name])))
        if peak > MAX_POSITION_M:
            raise UserError(f"{path}: column {column[name]!r} reaches {peak:.6g}, "
                            f"beyond {MAX_POSITION_M:g} m; positions must be in m (for a record "
                            f"in mm, scale {name} by 0.001)")
    peak = float(np.max(np.abs(signals["u"])))
    if peak > MAX_FORCE_N:
        raise UserError(f"{path}: column {column['u']!r} reaches {peak:.6g}, beyond "
                        f"{MAX_FORCE_N:g} N of any linear motor; u must be a force in N")
