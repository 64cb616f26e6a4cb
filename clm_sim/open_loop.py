"""A plant driven open loop by a measured input: the simulation system identification scores.

    record's input u (N) + initial state from its first output samples -> simulated position
    -> error against the measured position after those samples (RMSE, NRMSE, fit %)

The benchmark protocol of nonlinearbenchmark.org (EMPS and others) lets a model use the test
input and the first ``n`` (20) samples of the test output, nothing else: :func:`initial_state`
takes the position and velocity at the last of those samples from a least-squares parabola
through them (a constant acceleration over 20 ms), and the bristle states of pre-sliding
friction along their path; :func:`simulate_input` then runs the plant's own kernel (stick-slip,
every effect, the plant's sub-steps) with ``u[k]`` held over each sample, at the record's
sample rate. The simulated position is the true position of the model (no encoder: the
measured one carries the quantization).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from clm_sim import kernel
from clm_sim.effects import lower_effects
from clm_sim.errors import UserError
from clm_sim.plant import Plant

INIT_SAMPLES = 20  # the benchmark protocol's initialization window (EMPS, nonlinear_benchmarks)
# The fewest samples a score is taken over: a spread and a fit over a handful of samples say
# nothing about a model (one sample has no spread at all).
MIN_SCORED_SAMPLES = 100


@dataclass(frozen=True)
class InitialState:
    """The state at sample ``sample`` (the last of the window): position (m), velocity (m/s)
    and the Dahl bristle states (-1..1) of the plant's pre-sliding elements."""

    sample: int
    position_m: float
    velocity_m_s: float
    bristles: tuple[float, ...] = ()


def initial_state(y: np.ndarray, ts: float, plant: Plant, samples: int = INIT_SAMPLES
                  ) -> InitialState:
    """The state at sample ``samples - 1`` from ``y[:samples]`` (m) alone, sampled at ``ts``
    (s). A window that does not move (one encoder value) is at rest: velocity exactly 0, so a
    stage held by its friction stays stuck."""
    if not (isinstance(samples, int) and 3 <= samples < len(y)):
        raise UserError(f"init samples: need an integer in 3..{len(y) - 1}, got {samples!r}")
    w = np.asarray(y[:samples], dtype=np.float64)
    tk = (np.arange(samples) - (samples - 1)) * ts
    if np.ptp(w) == 0.0:
        x0, v0 = float(w[-1]), 0.0
    else:
        c = np.polyfit(tk, w, 2)
        x0, v0 = float(c[2]), float(c[1])
    terms = lower_effects(plant.effects)
    bristles = tuple(float(kernel.dahl_states(np.ascontiguousarray(w), float(length))[-1])
                     for length in terms.dahl_length)
    return InitialState(samples - 1, x0, v0, bristles)


def simulate_input(plant: Plant, u: np.ndarray, ts: float, state: InitialState
                   ) -> tuple[np.ndarray, np.ndarray]:
    """``(x, v)``: position (m) and velocity (m/s) at every sample of the input ``u`` (N, held
    over each sample of ``ts`` s) from ``state`` on; NaN before ``state.sample``. Raises
    ``UserError`` if the simulation diverges."""
    u = np.ascontiguousarray(u, dtype=np.float64)
    n = len(u)
    x, v = np.full(n, np.nan), np.full(n, np.nan)
    motor = plant.kernel_plant(ts)
    z = motor.effects.dahl_state
    if len(state.bristles) != len(z):
        raise UserError(f"initial state has {len(state.bristles)} bristle states, the plant "
                        f"{len(z)} pre-sliding elements")
    z[:] = state.bristles
    k0 = state.sample
    status = kernel.open_loop(u[k0:], float(state.position_m), float(state.velocity_m_s), motor,
                              x[k0:], v[k0:])
    if status:
        raise UserError(f"the open-loop simulation diverged at t = {(k0 + status - 1) * ts:.4f} "
                        f"s (position beyond 1 km)")
    return x, v


@dataclass(frozen=True)
class Score:
    """How well a simulated signal matches a measured one over ``samples`` samples:
    ``rmse`` (in the signal's unit), ``nrmse`` (RMSE over the measured signal's standard
    deviation) and ``fit_percent`` (``100*(1 - ||y - y_sim|| / ||y - mean y||)``, MATLAB's
    ``compare``), ``max_abs`` (largest error). ``nrmse`` and ``fit_percent`` are ``None`` where
    the measured signal does not vary (no spread to normalise by: :attr:`undefined` says so)."""

    rmse: float
    nrmse: float | None
    fit_percent: float | None
    max_abs: float
    samples: int

    def as_dict(self) -> dict:
        return {"rmse": self.rmse, "nrmse": self.nrmse, "fit_percent": self.fit_percent,
                "max_abs": self.max_abs, "samples": self.samples}

    @property
    def undefined(self) -> str:
        """Why NRMSE and fit are not defined (``""`` where they are)."""
        return "" if self.nrmse is not None else "the measured signal does not vary"

    def ratios(self) -> str:
        """``NRMSE x, fit y %`` as printed, or why they are undefined."""
        if self.nrmse is None:
            return f"NRMSE and fit undefined ({self.undefined}: no spread to normalise by)"
        return f"NRMSE {self.nrmse:.4g}, fit {self.fit_percent:.2f} %"


def score(measured: np.ndarray, simulated: np.ndarray, start: int) -> Score:
    """The :class:`Score` of ``simulated`` against ``measured`` from sample ``start`` on."""
    y = np.asarray(measured, dtype=np.float64)[start:]
    e = y - np.asarray(simulated, dtype=np.float64)[start:]
    spread = float(np.std(y))
    rmse = float(np.sqrt(np.mean(e ** 2)))
    dev = float(np.linalg.norm(y - np.mean(y)))
    if not (spread > 0 and dev > 0):  # JSON has no infinity; a score has no meaning there
        return Score(rmse, None, None, float(np.max(np.abs(e))), len(y))
    return Score(rmse, rmse / spread, 100.0 * (1.0 - float(np.linalg.norm(e)) / dev),
                 float(np.max(np.abs(e))), len(y))
