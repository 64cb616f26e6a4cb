"""Output-error refinement: a plant's parameters fitted to what its *simulation* gets wrong.

    plant (structure and start) + training record -> open-loop simulation from the record's input
    (clm_sim.open_loop, the benchmark's initialization) -> position error after the window
    -> scipy.optimize.least_squares over named parameters -> refined plant

The inverse-dynamics fits (LIP, the diagnosis) minimise a filtered *force* error; a simulation
integrates the force error twice, so a bias of a tenth of a newton, invisible in the force
residual, walks the simulated position away by millimetres. Refining the same physics on the
simulation error of the training record is the forward route to the same model. Which
parameters are free is named (``mass``, ``viscous``, ``coulomb``, ``stiffness`` and one
coefficient per effect that scales its force); nonlinear shape parameters (periods, Stribeck
velocities, pre-sliding lengths) stay where the diagnosis put them. Constant forces are merged
into one ``force_offset`` first (two offsets are one parameter).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np
import scipy.optimize

from clm_sim.effects import ForceOffset
from clm_sim.errors import UserError
from clm_sim.open_loop import INIT_SAMPLES, initial_state, simulate_input
from clm_sim.plant import THETA_NAMES, Plant
from clm_sim.record import Run

# The coefficient of each effect type that scales its force (N, N*s/m), refined with theta.
SCALES = {"force_offset": ("force_n",), "stribeck": ("peak",), "presliding": ("sliding",),
          "friction_asymmetry": ("viscous_pos", "viscous_neg")}
# Typical size of a change per unit (the optimizer's x_scale where the start is 0).
_FLOOR = {"mass": 1.0, "viscous": 10.0, "coulomb": 1.0, "stiffness": 10.0, "force_n": 1.0,
          "peak": 1.0, "sliding": 1.0, "viscous_pos": 10.0, "viscous_neg": 10.0}


def merge_offsets(plant: Plant) -> Plant:
    """``plant`` with all its ``force_offset`` effects summed into one (first in place)."""
    offsets = [e for e in plant.effects if isinstance(e, ForceOffset)]
    if len(offsets) <= 1:
        return plant
    total = ForceOffset(force_n=float(sum(e.force_n for e in offsets)))
    kept, done = [], False
    for e in plant.effects:
        if isinstance(e, ForceOffset):
            if not done:
                kept.append(total)
                done = True
            continue
        kept.append(e)
    return dataclasses.replace(plant, effects=tuple(kept))


def free_parameters(plant: Plant, theta: tuple[str, ...] = THETA_NAMES) -> list[tuple]:
    """The refined parameters: ``(name, effect index or None, field)`` for ``theta`` and each
    effect's coefficients of :data:`SCALES`."""
    out = [(k, None, k) for k in theta]
    for i, e in enumerate(plant.effects):
        for f in SCALES.get(e.type, ()):
            out.append((f"{e.type}[{i}].{f}", i, f))
    return out


def with_values(plant: Plant, params: list[tuple], values: np.ndarray) -> Plant:
    """``plant`` with the named parameters set to ``values`` (physical bounds kept by the
    plant and the effects' own checks)."""
    theta = {}
    effects = list(plant.effects)
    for (name, index, field), value in zip(params, values):
        if index is None:
            theta[field] = float(value)
        else:
            effects[index] = dataclasses.replace(effects[index], **{field: float(value)})
    return dataclasses.replace(plant, **theta, effects=tuple(effects))


@dataclass(frozen=True)
class OutputErrorFit:
    """The refined ``plant``, the training RMSE (m) before and after, the optimizer's stop
    (``status``, ``message``, ``nfev``), the parameters (start and end, by name) and the CPU
    time (s)."""

    plant: Plant
    rmse_start_m: float
    rmse_m: float
    converged: bool
    message: str
    nfev: int
    start: dict
    values: dict
    cpu_s: float


def refine(plant: Plant, run: Run, *, theta: tuple[str, ...] = THETA_NAMES,
           init_samples: int = INIT_SAMPLES, step: int = 1, max_nfev: int = 400
           ) -> OutputErrorFit:
    """Fit the free parameters of ``plant`` (:func:`free_parameters`) to the open-loop position
    error of ``run`` after its first ``init_samples`` samples (every ``step``-th sample in the
    cost), by trust-region least squares with a finite-difference Jacobian."""
    cpu0 = time.process_time()
    plant = merge_offsets(plant)
    params = free_parameters(plant, theta)
    start = np.array([getattr(plant, f) if i is None else getattr(plant.effects[i], f)
                      for _, i, f in params], dtype=float)
    lower = np.array([1e-3 * plant.mass if f == "mass" else
                      0.0 if f in ("viscous", "coulomb", "sliding") else -np.inf
                      for _, _, f in params])
    start = np.maximum(start, lower)
    scale = np.array([max(abs(v), _FLOOR[f]) for v, (_, _, f) in zip(start, params)])
    y = run.y
    keep = slice(init_samples, None, step)

    def residual(values):
        try:
            candidate = with_values(plant, params, values)
            state = initial_state(y, run.ts, candidate, init_samples)
            x, _ = simulate_input(candidate, run.u, run.ts, state)
        except UserError:  # a diverging or unphysical candidate: a large, finite cost
            return np.full(len(y[keep]), 1.0)
        return (x - y)[keep]

    r0 = residual(start)
    sol = scipy.optimize.least_squares(residual, start, bounds=(lower, np.inf), x_scale=scale,
                                       diff_step=1e-6, max_nfev=max_nfev, method="trf")
    refined = with_values(plant, params, sol.x)
    rmse = float(np.sqrt(np.mean(residual(sol.x) ** 2)))
    return OutputErrorFit(refined, float(np.sqrt(np.mean(r0 ** 2))), rmse, sol.status > 0,
                          str(sol.message), int(sol.nfev),
                          {n: float(v) for (n, _, _), v in zip(params, start)},
                          {n: float(v) for (n, _, _), v in zip(params, sol.x)},
                          time.process_time() - cpu0)
