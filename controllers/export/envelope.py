"""The envelope of the data a feedforward was fitted on, and the export's default limits from it.

A fitted model is a function of the positions, velocities and accelerations it saw and was fitted
to the forces applied then; beyond them it extrapolates (a network, freely). The default C export
therefore rejects a reference sample outside the data's position range, cuts the velocity and
acceleration the model reads to the data's, and clamps its force to the data's, each widened by
``MARGIN`` (docs/export.md says why that size). Inside the widened envelope nothing changes: the
function replayed is the function fitted.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clm_sim.errors import UserError

# The share by which the limits widen the data's envelope: a reference may reach 50 % beyond the
# data's speed, acceleration and force, and half the data's stroke beyond either end of it,
# before a limit acts. The product itself replays a model fitted on r1 (-0.1 to 0.1 m) on r2
# (0 to 0.17 m): 35 % of r1's stroke beyond its end, so a use the product makes needs at least
# that; a unit error (mm typed for m: 1000 times) or a step (a velocity of thousands of m/s) is
# far outside it.
MARGIN = 0.5
# A model whose force on a motion inside its data's envelope exceeds this many times the data's
# largest force is not a fit of that data (a mass typed in g, an exponent lost): refused.
ABSURD = 10.0


@dataclass(frozen=True)
class Envelope:
    """What a model was fitted on: the position range (m), the largest |velocity| (m/s) and
    |acceleration| (m/s^2) of the positions as the fit saw them (central differences, through
    the model's regression filter where it has one) and the largest |force| applied (N);
    ``source`` names the data."""

    position_m: tuple[float, float]
    velocity_m_s: float
    acceleration_m_s2: float
    force_n: float
    source: str

    @classmethod
    def of_record(cls, y, u, ts: float, source: str, cutoff_hz: float | None = None,
                  order: int = 4) -> "Envelope":
        """The envelope of positions ``y`` (m) and forces ``u`` (N) sampled at ``ts`` (s)."""
        y = np.asarray(y, dtype=np.float64)
        u = np.asarray(u, dtype=np.float64)
        if len(y) < 5 or not (np.all(np.isfinite(y)) and np.all(np.isfinite(u))):
            raise UserError(f"{source}: no usable positions and forces for the limits")
        v = (y[2:] - y[:-2]) / (2.0 * ts)
        a = (y[2:] - 2.0 * y[1:-1] + y[:-2]) / (ts * ts)
        if cutoff_hz and cutoff_hz < 0.5 / ts and len(y) > 100:
            import scipy.signal

            sos = scipy.signal.butter(order, cutoff_hz, fs=1.0 / ts, output="sos")
            v, a = scipy.signal.sosfiltfilt(sos, np.vstack([v, a]), axis=1)
        env = cls((float(np.min(y)), float(np.max(y))), float(np.max(np.abs(v))),
                  float(np.max(np.abs(a))), float(np.max(np.abs(u))), source)
        if not (env.position_m[1] > env.position_m[0] and env.velocity_m_s > 0
                and env.acceleration_m_s2 > 0 and env.force_n > 0):
            raise UserError(f"{source}: the data does not move or applies no force; it gives "
                            f"no limits")
        return env

    def limits(self, margin: float = MARGIN) -> dict:
        """The export's limits: the envelope widened by ``margin`` (see ``MARGIN``)."""
        lo, hi = self.position_m
        span = hi - lo
        return {"max_force": (1 + margin) * self.force_n, "r_min": lo - margin * span,
                "r_max": hi + margin * span, "v_max": (1 + margin) * self.velocity_m_s,
                "a_max": (1 + margin) * self.acceleration_m_s2}

    def describe(self) -> str:
        lo, hi = self.position_m
        return (f"{self.source}: {lo:.4g} to {hi:.4g} m, {self.velocity_m_s:.4g} m/s, "
                f"{self.acceleration_m_s2:.4g} m/s2, {self.force_n:.4g} N, margin {MARGIN:g}")
