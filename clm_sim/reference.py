"""Jerk-limited (third-order) point-to-point reference trajectories.

Each move between consecutive points is the time-optimal rest-to-rest S-curve under symmetric
bounds on velocity, acceleration and jerk: up to seven constant-jerk segments
(+j, 0, -j, cruise, -j, 0, +j). The profile is a piecewise cubic in time and is evaluated in
closed form at every sample, so position is exact to rounding and standstill samples equal the
point bit for bit.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np

from clm_sim.errors import UserError

# Jerk sign of the seven segments of a positive move: +j, 0, -j, cruise, -j, 0, +j.
_JERK_PATTERN = (1.0, 0.0, -1.0, 0.0, -1.0, 0.0, 1.0)


@dataclass(frozen=True)
class ReferenceSignals:
    """A sampled reference: equal-length 1-D float64 arrays.

    Attributes
    ----------
    t : numpy.ndarray
        Sample times in s.
    r : numpy.ndarray
        Position in m.
    v : numpy.ndarray
        Velocity in m/s.
    a : numpy.ndarray
        Acceleration in m/s^2.
    j : numpy.ndarray
        Jerk in m/s^3, piecewise constant: the value of the segment that contains ``t``.
    """

    t: np.ndarray
    r: np.ndarray
    v: np.ndarray
    a: np.ndarray
    j: np.ndarray


def _s_curve_times(
    distance_m: float, max_velocity: float, max_acceleration: float, max_jerk: float
) -> tuple[float, float, float]:
    """Segment durations of the time-optimal rest-to-rest move over ``|distance_m|``.

    Parameters
    ----------
    distance_m : float
        Signed move length in m; only its magnitude matters.
    max_velocity, max_acceleration, max_jerk : float
        Bounds in m/s, m/s^2 and m/s^3, all > 0.

    Returns
    -------
    tuple of float
        ``(t_jerk_s, t_acc_s, t_cruise_s)``: duration of each constant-jerk ramp, of each
        constant-acceleration segment and of the cruise segment. The move takes
        ``4 * t_jerk_s + 2 * t_acc_s + t_cruise_s``.
    """
    d, v_max, a_max, j_max = abs(distance_m), max_velocity, max_acceleration, max_jerk
    if d == 0.0:
        return 0.0, 0.0, 0.0
    # Speed up to v_max: a_max is reached only if v_max >= a_max^2 / j_max.
    t_jerk = min(a_max / j_max, math.sqrt(v_max / j_max))
    t_acc = max(v_max / (j_max * t_jerk) - t_jerk, 0.0)
    if v_max * (2.0 * t_jerk + t_acc) <= d:  # v_max reached: cruise covers the rest
        return t_jerk, t_acc, d / v_max - (2.0 * t_jerk + t_acc)
    # v_max not reached; peak speed v_p follows from d = v_p * (duration of speed-up).
    t_jerk = a_max / j_max
    if d >= 2.0 * a_max * t_jerk**2:  # a_max reached: d = v_p^2 / a_max + v_p * t_jerk
        v_peak = 0.5 * a_max * (math.sqrt(t_jerk**2 + 4.0 * d / a_max) - t_jerk)
        return t_jerk, max(v_peak / a_max - t_jerk, 0.0), 0.0
    return (0.5 * d / j_max) ** (1.0 / 3.0), 0.0, 0.0  # pure jerk ramps: d = 2 j t_jerk^3


@dataclass(frozen=True)
class PointToPoint:
    """Rest-to-rest jerk-limited moves through `points_m`, dwelling `dwell_s` at each point.

    ``duration_s()`` is the length of the motion (s) and ``sample(ts)`` its signals at sample
    time ``ts`` (``.r``: position, m). The configs' r1 (the training range, -0.1 to 0.1 m) and
    r2 (beyond it, 0 to 0.17 m) are two of these.

    Parameters
    ----------
    points_m : tuple of float
        Positions in m; the first is the start position. At least two entries; repeated
        points give a zero-length move, i.e. just dwell.
    dwell_s : float
        Standstill time in s at every point, also before the first and after the last move.
    max_velocity : float
        Bound on ``|v|`` in m/s.
    max_acceleration : float
        Bound on ``|a|`` in m/s^2.
    max_jerk : float
        Bound on ``|j|`` in m/s^3.

    Raises
    ------
    UserError
        Fewer than two points, a point or a bound that is not a finite number, a bound that
        is not positive, a negative dwell.

    Examples
    --------
    >>> from clm_sim import PointToPoint
    >>> move = PointToPoint(points_m=(0.0, 0.01), dwell_s=0.1)  # 10 mm, 0.1 s at rest each end
    >>> r = move.sample(1e-4).r                                 # m, at 10 kHz
    >>> len(r), float(r[0]), float(r[-1])
    (4167, 0.0, 0.01)
    """

    points_m: tuple[float, ...]
    dwell_s: float = 0.5
    max_velocity: float = 0.05
    max_acceleration: float = 4.0
    max_jerk: float = 1000.0

    def __post_init__(self) -> None:
        try:
            points = tuple(float(p) for p in self.points_m)
        except (TypeError, ValueError):
            raise UserError(
                f"reference: points_m must be a sequence of numbers, got {self.points_m!r}"
            ) from None
        if len(points) < 2:
            raise UserError(f"reference: points_m needs at least 2 points, got {len(points)}")
        for i, p in enumerate(points):
            if not math.isfinite(p):
                raise UserError(f"reference: points_m[{i}] must be finite, got {p:g}")
        object.__setattr__(self, "points_m", points)  # store a hashable tuple of floats
        for name, unit in (
            ("dwell_s", "s"),
            ("max_velocity", "m/s"),
            ("max_acceleration", "m/s^2"),
            ("max_jerk", "m/s^3"),
        ):
            value = getattr(self, name)
            if not isinstance(value, numbers.Real) or isinstance(value, bool):
                raise UserError(f"reference: {name} must be a number in {unit}, got {value!r}")
            if not math.isfinite(value):
                raise UserError(f"reference: {name} must be finite, got {value:g}")
            if name == "dwell_s" and value < 0.0:
                raise UserError(f"reference: dwell_s must be >= 0 s, got {value:g}")
            if name != "dwell_s" and value <= 0.0:
                raise UserError(f"reference: {name} must be > 0 {unit}, got {value:g}")
        try:  # limits too small for the distances give times no float holds
            moves = [sum(_s_curve_times(b - a, self.max_velocity, self.max_acceleration,
                                        self.max_jerk)) for a, b in zip(points, points[1:])]
        except (OverflowError, ZeroDivisionError):
            moves = [math.inf]
        if not all(math.isfinite(m) for m in moves):
            raise UserError("reference: max_velocity, max_acceleration and max_jerk are too "
                            "small for the moves between points_m: a move would take forever; "
                            "are they in m/s, m/s^2 and m/s^3?")

    def _segments(self) -> tuple[np.ndarray, ...]:
        """Constant-jerk segments as arrays ``(start_s, r0_m, v0, a0, jerk)``.

        Every non-empty segment is listed with the state at its start; a final open-ended rest
        segment at the last point starts at ``duration_s()``.
        """
        rows: list[tuple[float, float, float, float, float]] = []
        t = 0.0

        def rest(point_m: float, length_s: float) -> None:
            nonlocal t
            if length_s > 0.0:
                rows.append((t, point_m, 0.0, 0.0, 0.0))
                t += length_s

        rest(self.points_m[0], self.dwell_s)
        for start_m, end_m in zip(self.points_m[:-1], self.points_m[1:]):
            t_jerk, t_acc, t_cruise = _s_curve_times(
                end_m - start_m, self.max_velocity, self.max_acceleration, self.max_jerk
            )
            lengths = (t_jerk, t_acc, t_jerk, t_cruise, t_jerk, t_acc, t_jerk)
            jerk_max = math.copysign(self.max_jerk, end_m - start_m)
            r, v, a = start_m, 0.0, 0.0  # from the point itself: rounding never accumulates
            for length, sign in zip(lengths, _JERK_PATTERN):
                if length == 0.0:
                    continue
                j = sign * jerk_max
                rows.append((t, r, v, a, j))
                r, v, a = _cubic(r, v, a, j, length)
                t += length
            rest(end_m, self.dwell_s)
        rows.append((t, self.points_m[-1], 0.0, 0.0, 0.0))
        return tuple(np.array(col, dtype=np.float64) for col in zip(*rows))

    def duration_s(self) -> float:
        """Total length of the reference in s: all dwells and all moves."""
        return float(self._segments()[0][-1])

    def sample(self, ts: float) -> ReferenceSignals:
        """Evaluate the reference at ``t = k * ts``, ``k = 0 .. ceil(duration_s() / ts)``.

        Parameters
        ----------
        ts : float
            Sample time in s, > 0.

        Returns
        -------
        ReferenceSignals
            Exact piecewise-cubic samples; after the end the signals hold the last point.
        """
        if not (isinstance(ts, numbers.Real) and math.isfinite(ts) and ts > 0.0):
            raise UserError(f"reference: ts must be a finite number > 0 s, got {ts!r}")
        start, r0, v0, a0, jerk = self._segments()
        t = np.arange(math.ceil(start[-1] / ts) + 1, dtype=np.float64) * ts
        k = np.searchsorted(start, t, side="right") - 1
        r, v, a = _cubic(r0[k], v0[k], a0[k], jerk[k], t - start[k])
        return ReferenceSignals(t=t, r=r, v=v, a=a, j=jerk[k].copy())


def _cubic(r0, v0, a0, j, tau):
    """State ``(r, v, a)`` after ``tau`` s of constant jerk ``j`` from ``(r0, v0, a0)``.

    Horner form, so a rest segment (``v0 = a0 = j = 0``) returns ``r0`` bit for bit.
    """
    r = r0 + tau * (v0 + tau * (a0 / 2.0 + tau * (j / 6.0)))
    v = v0 + tau * (a0 + tau * (j / 2.0))
    a = a0 + tau * j
    return r, v, a
