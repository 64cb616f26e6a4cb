"""Identification by simulation error: a plant's parameters fitted to what its *simulation* gets
wrong, from several starts.

    structure (a plant) + starts + record -> open-loop simulation from the record's input
    (clm_sim.open_loop: initial state from a parabola through the first ``init_samples``
    positions) -> position error after that window -> scipy.optimize.least_squares from every
    start -> the lowest end, each start's stop, whether the starts agree

The inverse-dynamics fits (LIP, the diagnosis) minimise a filtered *force* error; a simulation
integrates the force error twice, so a bias of a tenth of a newton, invisible in the force
residual, walks the simulated position away by millimetres. Fitting the same physics on the
simulation error is the forward route (output error, the criterion of the simulation
benchmarks). The free parameters are named (:data:`UNITS`): the rigid body's and one coefficient
per effect that scales its force; nonlinear shape parameters (periods, Stribeck velocities,
pre-sliding lengths) stay where the structure puts them. Constant forces are merged into one
``offset`` first (two offsets are one parameter); a direction asymmetry is one odd viscous
coefficient (``asym_viscous``: ``+d*v`` moving up, ``-d*v`` moving down; an even part would be
``viscous``, an odd Coulomb part is an offset).

**Convergence test** (stated, not a step-size stop): trust-region least squares (forward
differences of relative step ``DIFF_STEP``) is restarted from its end with a fresh trust region
until a restart lowers the cost by less than ``RESTART_GAIN`` (relative; at most ``RESTARTS``
times); the fit has *converged* where that last run ended by the gradient test (first-order
optimality below ``GTOL``) or the cost-decrease test (below a relative ``FTOL`` per step). The
step-size test is off (``xtol`` 1e-15): a run that ends on it, or on ``max_nfev`` evaluations,
is a *stop*, reported as such. A start *reached* the lowest end where it converged, its
training RMSE is within ``agree_rtol`` of the lowest found and every free parameter within
``PARAM_RTOL`` of the lowest end's (relative to the parameter's size, or its typical size where
that is larger): equal costs at other parameters are another point of a flat valley, not the
same end. The fit is a *measurement* where the lowest end converged and at least two starts
reached it; the starts *agree* where every converged start reached it.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np
import scipy.optimize

from clm_sim.effects import lower_effects
from clm_sim.effects.friction import FrictionAsymmetry, Presliding, Stribeck
from clm_sim.effects.position import Cogging, ForceOffset, ForceRipple
from clm_sim.errors import UserError
from clm_sim.open_loop import INIT_SAMPLES, initial_state, simulate_input
from clm_sim.plant import Plant
from clm_sim.run import Run

# Every parameter a simulation-error fit can free, with its unit, in this order.
UNITS = {"mass": "kg", "viscous": "N·s/m", "coulomb": "N", "stiffness": "N/m", "offset": "N",
         "asym_viscous": "N·s/m", "stribeck": "N", "presliding": "N", "cogging": "N",
         "force_ripple": "1"}
# The effect each non-rigid-body parameter scales.
_EFFECT = {"offset": ForceOffset, "asym_viscous": FrictionAsymmetry, "stribeck": Stribeck,
           "presliding": Presliding, "cogging": Cogging, "force_ripple": ForceRipple}
# Typical size of a change (the optimizer's scale and the perturbations' where a value is ~0).
_FLOOR = {"mass": 1.0, "viscous": 10.0, "coulomb": 1.0, "stiffness": 10.0, "offset": 1.0,
          "asym_viscous": 10.0, "stribeck": 1.0, "presliding": 1.0, "cogging": 0.1,
          "force_ripple": 0.01}
_NONNEGATIVE = ("viscous", "coulomb", "presliding")

GTOL = 1e-8  # first-order optimality at which a fit has converged (scipy's scaled test)
FTOL = 1e-10  # relative decrease of the cost per step below which a fit has converged
AGREE_RTOL = 0.01  # starts whose training RMSEs lie within 1 % of the lowest agree
# ... and whose parameters lie within 2 % of the lowest end's (of each one's size or typical
# size): ten times finer than the perturbed starts' spread, so two starts that reach it from
# different sides found one end, not two points of a valley.
PARAM_RTOL = 0.02
MAX_NFEV = 500  # evaluations of one start, its restarts included
DIFF_STEP = 1e-4
JAC = '2-point'
RESTARTS = 3  # at most; until a restart lowers the cost by < RESTART_GAIN
RESTART_GAIN = 1e-6


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


def structure_parameters(plant: Plant) -> tuple[str, ...]:
    """The parameters ``plant``'s structure carries, in :data:`UNITS` order: mass, viscous and
    Coulomb friction, the stiffness where it is not 0, and one per effect that has a
    coefficient here. Two effects of one type (other than offsets) are refused: one name, one
    number."""
    plant = merge_offsets(plant)
    types = [type(e) for e in plant.effects]
    for cls in set(types):
        if types.count(cls) > 1 and cls is not ForceOffset:
            raise UserError(f"plant: {types.count(cls)} {cls.type} effects; a simulation-error "
                            f"fit frees one coefficient per effect type")
    names = ["mass", "viscous", "coulomb"] + (["stiffness"] if plant.stiffness != 0.0 else [])
    names += [n for n, cls in _EFFECT.items() if cls in types]
    return tuple(n for n in UNITS if n in names)


def _effect(plant: Plant, name: str):
    cls = _EFFECT[name]
    for i, e in enumerate(plant.effects):
        if isinstance(e, cls):
            return i, e
    raise UserError(f"the structure has no {cls.type} effect for the parameter {name!r}")


def value(plant: Plant, name: str) -> float:
    """The parameter ``name`` of ``plant`` (:data:`UNITS`)."""
    if name not in _EFFECT:
        return float(getattr(plant, name))
    _, e = _effect(plant, name)
    return float({"offset": lambda: e.force_n,
                  "asym_viscous": lambda: (e.viscous_pos - e.viscous_neg) / 2,
                  "stribeck": lambda: e.peak, "presliding": lambda: e.sliding,
                  "cogging": lambda: e.amplitude, "force_ripple": lambda: e.amplitude}[name]())


def with_values(plant: Plant, values: dict[str, float]) -> Plant:
    """``plant`` with the named parameters set (the plant's and the effects' own checks keep the
    physical bounds: a ``UserError`` says which)."""
    theta = {k: float(v) for k, v in values.items() if k not in _EFFECT}
    effects = list(plant.effects)
    for name, v in values.items():
        if name not in _EFFECT:
            continue
        i, e = _effect(dataclasses.replace(plant, effects=tuple(effects)), name)
        v = float(v)
        if name == "offset":
            effects[i] = ForceOffset(force_n=v)
        elif name == "asym_viscous":
            effects[i] = dataclasses.replace(e, viscous_pos=v, viscous_neg=-v)
        elif name == "presliding":
            effects[i] = Presliding.with_length(v, e.length)
        elif name == "stribeck":
            effects[i] = dataclasses.replace(e, peak=v)
        else:
            effects[i] = dataclasses.replace(e, amplitude=v)
    return dataclasses.replace(plant, **theta, effects=tuple(effects))


@dataclass(frozen=True)
class Stop:
    """Where one start ended: its ``label``, the free parameters at the start and the end (by
    name), the training RMSE (m) there, scipy's ``status`` and ``message``, evaluations,
    first-order optimality and CPU seconds."""

    label: str
    start: dict
    end: dict
    rmse_start_m: float
    rmse_m: float
    status: int
    message: str
    nfev: int
    optimality: float
    cpu_s: float

    @property
    def converged(self) -> bool:
        """The gradient (status 1) or cost-decrease (2, 4) test reached; not a step-size stop
        (3) or the evaluation cap (0)."""
        return self.status in (1, 2, 4)

    def line(self) -> str:
        why = {1: "gradient test", 2: "cost-decrease test", 4: "gradient and cost tests",
               3: "step-size stop, not converged", 0: "evaluation cap, not converged",
               5: "a restart still lowered the cost, not converged"}
        return (f"{self.label}: {'converged' if self.converged else 'stopped'} after "
                f"{self.nfev} evaluations ({why.get(self.status, self.message)}, optimality "
                f"{self.optimality:.2g}); training RMSE {self.rmse_start_m * 1e3:.4g} -> "
                f"{self.rmse_m * 1e3:.4g} mm")

    def to_json(self) -> dict:
        return {**dataclasses.asdict(self), "converged": self.converged}


@dataclass(frozen=True)
class SimulationFit:
    """A simulation-error fit from several starts: the lowest end's ``plant``, the ``free`` and
    ``held`` parameters (held: name -> value), every start's :class:`Stop` and the tolerance
    the starts are compared by (relative, on the training RMSE)."""

    plant: Plant
    free: tuple[str, ...]
    held: dict
    stops: tuple[Stop, ...]
    agree_rtol: float = AGREE_RTOL
    init_samples: int = INIT_SAMPLES
    param_rtol: float = PARAM_RTOL

    @property
    def best(self) -> Stop:
        return min(self.stops, key=lambda s: s.rmse_m)

    @property
    def rmse_m(self) -> float:
        return self.best.rmse_m

    def reached(self) -> list[Stop]:
        """The converged stops that ended within ``agree_rtol`` of the lowest RMSE and with
        every free parameter within ``param_rtol`` of the lowest end's (module docstring)."""
        best = self.best
        low = best.rmse_m

        def near(s: Stop) -> bool:
            return all(abs(s.end[k] - best.end[k]) <= self.param_rtol * max(abs(best.end[k]),
                                                                              _FLOOR[k])
                       for k in self.free)

        return [s for s in self.stops if s.converged and s.rmse_m <= low * (1 + self.agree_rtol)
                and near(s)]

    @property
    def agree(self) -> bool:
        """Every converged start ends within the tolerance of the lowest end."""
        return all(s in self.reached() for s in self.stops if s.converged)

    @property
    def measured(self) -> bool:
        """The lowest end converged and at least two starts reached it."""
        return self.best.converged and len(self.reached()) >= 2

    def spread(self) -> dict[str, float]:
        """Per free parameter, the largest relative difference between the ends that reached
        the lowest RMSE (0 where fewer than two did)."""
        ends = self.reached()
        out = {}
        for k in self.free:
            v = [s.end[k] for s in ends]
            out[k] = 0.0 if len(v) < 2 else (max(v) - min(v)) / max(abs(self.best.end[k]), 1e-12)
        return out

    def verdict(self) -> str:
        n = len(self.reached())
        return (f"{'a measurement' if self.measured else 'not a measurement'}: the lowest "
                f"end {'converged' if self.best.converged else 'did not converge'}; {n} of "
                f"{len(self.stops)} starts reached it (within {100 * self.agree_rtol:g} % of its "
                f"training RMSE, {self.rmse_m * 1e3:.4g} mm, and {100 * self.param_rtol:g} % of "
                f"its parameters)"
                + ("" if self.agree else "; a converged start ended elsewhere (another "
                   "minimum, or another point of a flat valley)"))

    def summary(self) -> str:
        lines = [f"{k:12s} {self.best.end[k]:12.6g} {UNITS[k]:6s} (starts' spread "
                 f"{100 * s:.2g} %)" for k, s in self.spread().items()]
        lines += [f"{k:12s} {v:12.6g} {UNITS[k]:6s} (held)" for k, v in self.held.items()]
        lines += [f"start {s.line()}" for s in self.stops]
        lines.append(self.verdict())
        return "\n".join(lines)

    def to_json(self) -> dict:
        return {"free": list(self.free), "held": self.held, "init_samples": self.init_samples,
                "criterion": "open-loop simulation error of the position (RMSE after the "
                             "initialization window)",
                "convergence": {"gtol": GTOL, "ftol": FTOL, "xtol": 1e-15,
                                "diff_step": DIFF_STEP, "restarts": RESTARTS,
                                "restart_gain": RESTART_GAIN},
                "agree_rtol": self.agree_rtol, "param_rtol": self.param_rtol,
                "reached": len(self.reached()), "agree": self.agree, "measured": self.measured,
                "rmse_m": self.rmse_m, "best": self.best.label,
                "stops": [s.to_json() for s in self.stops]}


def training_rmse(plant: Plant, run: Run, init_samples: int = INIT_SAMPLES) -> float:
    """Open-loop RMSE (m) of ``plant`` on ``run`` after its first ``init_samples``."""
    state = initial_state(run.y, run.ts, plant, init_samples)
    x, _ = simulate_input(plant, run.u, run.ts, state)
    return float(np.sqrt(np.mean((x - run.y)[init_samples:] ** 2)))


@dataclass(frozen=True)
class Conditioning:
    """How well the simulation error determines a structure's parameters at a point: the
    singular values of the Jacobian of the simulated position (m) with respect to the
    parameters in units of their size (or typical size), relative to the largest, and the
    weakest direction (its component per parameter, largest first), by central differences of
    relative step ``rel``."""

    rel: float
    singular: tuple[float, ...]
    weakest: dict

    def line(self) -> str:
        return (f"singular values (relative) " + ", ".join(f"{x:.2g}" for x in self.singular)
                + "; weakest direction " + ", ".join(f"{k} {v:+.2f}"
                                                     for k, v in self.weakest.items()))

    def to_json(self) -> dict:
        return dataclasses.asdict(self)


def conditioning(plant: Plant, run: Run, names, init_samples: int = INIT_SAMPLES,
                 rel: float = 1e-3) -> Conditioning:
    """:class:`Conditioning` of ``plant``'s parameters ``names`` on ``run``. A direction with
    a small singular value moves the simulated position little: the simulation error does not
    determine that combination (the route is to hold or drop the terms that make it)."""
    state = initial_state(run.y, run.ts, plant, init_samples)
    cols = []
    for k in names:
        v = value(plant, k)
        h = rel * max(abs(v), _FLOOR[k])
        up, _ = simulate_input(with_values(plant, {k: v + h}), run.u, run.ts, state)
        down, _ = simulate_input(with_values(plant, {k: v - h}), run.u, run.ts, state)
        cols.append((up - down)[init_samples:] / (2 * rel))
    _, sv, vt = np.linalg.svd(np.column_stack(cols) / np.sqrt(len(cols[0])),
                              full_matrices=False)
    w = vt[-1] * (1.0 if vt[-1][np.argmax(np.abs(vt[-1]))] > 0 else -1.0)
    order = np.argsort(-np.abs(w))
    return Conditioning(rel, tuple(float(x / sv[0]) for x in sv),
                        {names[i]: float(w[i]) for i in order})


def perturbed(values: dict[str, float], rng: np.random.Generator, spread: float = 0.2
              ) -> dict[str, float]:
    """``values`` moved by ``spread`` of their size (or of the parameter's typical size where
    that is larger), normally distributed; non-negative parameters stay so."""
    out = {}
    for k, v in values.items():
        w = v + spread * max(abs(v), _FLOOR[k]) * rng.standard_normal()
        out[k] = abs(w) if k in _NONNEGATIVE else w
    return out


def fit(structure: Plant, run: Run, starts: list[tuple[str, dict]], *,
        hold: dict[str, float] | None = None, init_samples: int = INIT_SAMPLES,
        max_nfev: int = MAX_NFEV, agree_rtol: float = AGREE_RTOL) -> SimulationFit:
    """Fit the parameters of ``structure`` (:func:`structure_parameters`, less those in
    ``hold``, which are set to their given values) to the open-loop position error of ``run``
    from each start (``(label, {name: value})``; names missing from a start keep the
    structure's value), by trust-region least squares with a finite-difference Jacobian
    (module docstring: the convergence test)."""
    structure = merge_offsets(structure)
    hold = dict(hold or {})
    names = structure_parameters(structure)
    unknown = sorted(set(hold) - set(names))
    if unknown:
        raise UserError(f"hold: {', '.join(unknown)} not among the structure's parameters "
                        f"({', '.join(names)})")
    free = tuple(n for n in names if n not in hold)
    if not free:
        raise UserError(f"hold: every parameter held ({', '.join(names)}); nothing to fit")
    base = with_values(structure, hold)
    y = run.y
    n = len(y) - init_samples

    def plant_at(x):
        return with_values(base, dict(zip(free, x)))

    # The initial state depends on the record and the pre-sliding lengths alone (no free
    # parameter moves a length; a pre-sliding force of 0 drops its element): made once per set
    # of lengths, not per evaluation (its least-squares parabola cost as much as a simulation).
    states = {}

    def state_of(candidate):
        key = tuple(lower_effects(candidate.effects).dahl_length)
        if key not in states:
            states[key] = initial_state(y, run.ts, candidate, init_samples)
        return states[key]

    def residual(x):
        try:
            candidate = plant_at(x)
            sim, _ = simulate_input(candidate, run.u, run.ts, state_of(candidate))
        except UserError:  # an unphysical or diverging candidate: a large, finite cost
            return np.full(n, 1.0)
        return (sim - y)[init_samples:]

    stops = []
    for label, given in starts:
        cpu = time.process_time()
        x0 = np.array([float(given.get(k, value(base, k))) for k in free])
        lower = np.array([0.0 if k in _NONNEGATIVE else 1e-3 * x0[i] if k == "mass"
                          else -np.inf for i, k in enumerate(free)])
        x0 = np.maximum(x0, lower)
        scale = np.array([max(abs(v), _FLOOR[k]) for v, k in zip(x0, free)])
        r0 = residual(x0)
        sol = scipy.optimize.least_squares(
            residual, x0, bounds=(lower, np.inf), x_scale=scale, diff_step=DIFF_STEP,
            method="trf", ftol=FTOL, gtol=GTOL, xtol=1e-15, max_nfev=max_nfev, jac=JAC)
        nfev, status, message = sol.nfev, sol.status, sol.message
        settled = False
        for _ in range(RESTARTS):  # a fresh trust region from the end: the convergence test
            if nfev >= max_nfev:
                break
            again = scipy.optimize.least_squares(
                residual, sol.x, bounds=(lower, np.inf), x_scale=scale, diff_step=DIFF_STEP,
                method="trf", ftol=FTOL, gtol=GTOL, xtol=1e-15, max_nfev=max_nfev - nfev,
                jac=JAC)
            nfev += again.nfev
            gain = 1 - again.cost / sol.cost
            sol = again if again.cost < sol.cost else sol
            status, message = again.status, again.message
            if gain < RESTART_GAIN:
                settled = True
                break
        if not settled and status != 0:  # the restarts still lowered the cost: no end yet
            status, message = 5, "a restart still lowered the cost"
        stops.append(Stop(label, dict(zip(free, map(float, x0))), dict(zip(free, map(float,
                                                                                  sol.x))),
                          float(np.sqrt(np.mean(r0 ** 2))),
                          float(np.sqrt(np.mean(sol.fun ** 2))), int(status),
                          str(message), int(nfev), float(sol.optimality),
                          time.process_time() - cpu))
    best = min(stops, key=lambda s: s.rmse_m)
    return SimulationFit(plant_at(np.array([best.end[k] for k in free])), free, hold,
                         tuple(stops), agree_rtol, init_samples)


def model_file(plant: Plant, ts: float, *, name: str, description: str) -> dict:
    """A model file (``clm-sim simulate``, ``clm-sim diagnose --model``) of ``plant`` at the
    sample time ``ts`` (s), every number at full precision."""
    return {"name": name, "description": description, "ts": float(ts),
            "plant": {**plant.theta(), "encoder_resolution": float(plant.encoder_resolution),
                      "substeps": int(plant.substeps),
                      "effects": [e.as_config() for e in plant.effects]}}
