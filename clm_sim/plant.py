"""The coreless linear motor: rigid mass with friction, stiffness and named parasitic effects.

``m*a = u_motor - fv*v - fc*sign(v) - fk*y - sum(effect forces)``, read through an encoder.

Defaults are the CLM identified in the PGNN paper (m 18.8 kg, fv 172 N*s/m, fc 7.21 N, fk ~ 0) plus
the parasitic forces an ironless linear motor on ball-bearing guides with a cable carrier has
(see ``default_effects`` and the README): no cogging (there is no iron to attract the magnets), a
1 % commutation force ripple over the magnet pitch, a cable-carrier force of a few newtons that
stiffens towards the stroke ends, and a small Stribeck peak from the guides.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import scipy.linalg

from clm_sim.effects import lower_effects, total_force
from clm_sim.effects.base import Effect, EffectArrays
from clm_sim.effects.friction import Stribeck
from clm_sim.effects.position import CableSlab, ForceRipple
from clm_sim.errors import UserError
from clm_sim.rigid_body import THETA_NAMES, rigid_body

THETA_UNITS = {"mass": "kg", "viscous": "N·s/m", "coulomb": "N", "stiffness": "N/m"}


@functools.lru_cache(maxsize=64)
def _substep_matrices(mass, viscous, stiffness, substeps, ts):
    # Cached: sweeps and replays simulate the same plant many times; expm is not free.
    h = ts / substeps
    m = np.zeros((3, 3))
    m[:2, :2] = [[0.0, 1.0], [-stiffness / mass, -viscous / mass]]
    m[1, 2] = 1.0 / mass
    e = scipy.linalg.expm(m * h)
    ad, bd = np.ascontiguousarray(e[:2, :2]), np.ascontiguousarray(e[:2, 2])
    ad.flags.writeable = bd.flags.writeable = False
    return h, ad, bd
# Hard bounds, far beyond any machine (the plausible range is a warning:
# experiments.records.suspicions.MASS_RANGE_KG): a value past them is a mistake of units or a typo,
# and overflows the simulation (a mass of 1e308 kg times an acceleration is inf).
PHYSICAL_BOUND = {"mass": 1e6, "viscous": 1e9, "coulomb": 1e9, "stiffness": 1e12}
UNITS = {"mass": "kg", "viscous": "N s/m", "coulomb": "N", "stiffness": "N/m"}
MIN_MASS_KG = 1e-6
MAX_ENCODER_RESOLUTION = 1e-3  # m per count; a coarser value is a unit mistake (um or nm)


def default_effects() -> tuple[Effect, ...]:
    """Parasitic forces of a typical ironless CLM stage; each choice is argued in the README."""
    return (
        ForceRipple(amplitude=0.01, period=0.024, phase=0.0),
        CableSlab(coefficients=(0.0, 10.0, 0.0, 2000.0), center=0.0),
        Stribeck(peak=1.0, velocity=0.001, exponent=2.0),
    )


class KernelPlant(NamedTuple):
    """A plant as the compiled simulator takes it, each part by its name: the sub-step ``h``
    (s), ``substeps`` per sample, the exact propagation of the linear part over a sub-step
    (``[x, v] <- ad @ [x, v] + bd * F``), the rigid-body parameters (kg, N*s/m, N, N/m) and the
    effects' arrays. Numba's cache index names this type and :class:`EffectArrays` by their
    modules: a cache written before either moved fails to load (clear
    ``clm_sim/__pycache__/kernel.*``)."""

    h: float
    substeps: int
    ad: np.ndarray
    bd: np.ndarray
    mass: float
    viscous: float
    coulomb: float
    stiffness: float
    effects: EffectArrays


@dataclass(frozen=True)
class Plant:
    """Motor parameters in SI units and the encoder that reads it.

    The forward plant ``m a = u - fv v - fc sign(v) - fk y - sum(effect forces)``, with real
    sticking at rest, integrated exactly between sub-steps; the default is the simulated CLM
    (18.8 kg, its friction and parasitic forces, a 0.1 µm encoder).

    Parameters
    ----------
    mass : float
        Moving mass, kg (> 0).
    viscous : float
        Viscous friction, N*s/m (>= 0).
    coulomb : float
        Coulomb friction, N (>= 0); the breakaway level at rest.
    stiffness : float
        Position stiffness, N/m (a cable or a spring; may be negative).
    effects : tuple of Effect
        Parasitic forces (``clm_sim.effects``). Left out: the default stage's
        (``clm_sim.plant.default_effects()``: force ripple, cable slab, Stribeck);
        ``effects=()`` for the rigid body alone.
    encoder_resolution : float
        m per count (0: the ideal position); at most 1 mm.
    substeps : int
        Integration sub-steps per sample (halving the sub-step must move the trajectory by
        less than one count; tested).

    Raises
    ------
    UserError
        A parameter that is not finite or out of its range, an encoder coarser than 1 mm per
        count (a unit mistake), Stribeck dips deeper than the Coulomb friction.

    Examples
    --------
    >>> from clm_sim import Plant
    >>> from clm_sim.effects import Cogging
    >>> Plant().theta()
    {'mass': 18.8, 'viscous': 172.0, 'coulomb': 7.21, 'stiffness': 0.0}
    >>> [e.type for e in Plant().effects]
    ['force_ripple', 'cable_slab', 'stribeck']
    >>> machine = Plant(mass=20.0, effects=(Cogging(amplitude=3.0, period=0.016),))
    >>> float(machine.inverse_force(y=0.004, v=0.0, a=1.0))  # 20 kg * 1 m/s^2 + 3 N * sin(pi/2)
    23.0
    """

    mass: float = 18.8
    viscous: float = 172.0
    coulomb: float = 7.21
    stiffness: float = 0.0
    effects: tuple[Effect, ...] = field(default_factory=default_effects)
    encoder_resolution: float = 1e-7
    substeps: int = 2

    def __post_init__(self):
        object.__setattr__(self, "effects", tuple(self.effects))
        checks = {"mass": (self.mass, False), "viscous": (self.viscous, True),
                  "coulomb": (self.coulomb, True), "encoder_resolution":
                  (self.encoder_resolution, True)}
        for key, (value, zero_ok) in checks.items():
            if not (isinstance(value, (int, float)) and math.isfinite(value)):
                raise UserError(f"plant: {key} must be a finite number, got {value!r}")
            if value < 0 or (value == 0 and not zero_ok):
                raise UserError(f"plant: {key} must be {'>= 0' if zero_ok else '> 0'}, "
                                f"got {value!r}")
        for key, value in (("mass", self.mass), ("viscous", self.viscous),
                           ("coulomb", self.coulomb), ("stiffness", self.stiffness)):
            if isinstance(value, (int, float)) and abs(value) > PHYSICAL_BOUND[key]:
                raise UserError(f"plant: {key} {value:g} is beyond any machine (at most "
                                f"{PHYSICAL_BOUND[key]:g} {UNITS[key]}); is it in SI units?")
        if self.mass < MIN_MASS_KG:
            raise UserError(f"plant: mass {self.mass:g} kg is below {MIN_MASS_KG:g} kg, lighter "
                            f"than any moving part; is it in kg?")
        if self.encoder_resolution > MAX_ENCODER_RESOLUTION:
            raise UserError(f"plant: encoder_resolution is in m per count; "
                            f"{self.encoder_resolution!r} m is coarser than any linear encoder "
                            f"(at most {MAX_ENCODER_RESOLUTION:g} m); is it in um or nm?")
        if not (isinstance(self.stiffness, (int, float)) and math.isfinite(self.stiffness)):
            raise UserError(f"plant: stiffness must be a finite number, got {self.stiffness!r}")
        dips = sum(e.peak for e in self.effects if isinstance(e, Stribeck))
        if self.coulomb + dips < 0:
            raise UserError(f"plant: the stribeck peaks sum to {dips!r} N, below minus the "
                            f"coulomb friction {self.coulomb!r} N: a friction dip cannot push "
                            f"the stage at standstill")
        if not (isinstance(self.substeps, int) and 1 <= self.substeps <= 1000):
            raise UserError(f"plant: substeps must be an integer in 1..1000, got {self.substeps!r}")

    def theta(self) -> dict[str, float]:
        """The LIP parameters ``{mass, viscous, coulomb, stiffness}``."""
        return {name: float(getattr(self, name)) for name in THETA_NAMES}

    def inverse_force(self, y, v, a, u=None) -> np.ndarray:
        """Force (N) the motor must supply for the motion ``(y, v, a)``; ``u`` feeds force ripple."""
        y, v, a = (np.asarray(z, dtype=float) for z in (y, v, a))
        base = rigid_body(self.theta(), a, v, np.sign(v), y)
        return base + total_force(self.effects, y, v, base if u is None else u)

    def motor_command(self, y, v, a) -> np.ndarray:
        """The motor command (N) that produces the motion ``(y, v, a)`` exactly: the fixed point
        of ``u = inverse_force(y, v, a, u)``, since effects that scale the motor force (ripple,
        a track end) depend on ``u``. The same bits as :meth:`inverse_force` for a plant whose
        effects do not. Converges while the motor force is scaled by a factor in (0, 2)."""
        u = self.inverse_force(y, v, a)
        for _ in range(200):
            nxt = self.inverse_force(y, v, a, u)
            if np.max(np.abs(nxt - u), initial=0.0) <= 1e-13 * max(1.0, float(
                    np.max(np.abs(nxt), initial=0.0))):
                return nxt
            u = nxt
        raise UserError("plant: the motor command did not converge (a motor-force factor "
                        "outside (0, 2))")

    def substep_matrices(self, ts: float) -> tuple[float, np.ndarray, np.ndarray]:
        """``(h, ad, bd)``: exact propagation of the linear part over one sub-step of ``h`` s
        for a constant force, ``[y, v] <- ad @ [y, v] + bd * F``."""
        return _substep_matrices(float(self.mass), float(self.viscous), float(self.stiffness),
                                 self.substeps, float(ts))

    def kernel_plant(self, ts: float) -> KernelPlant:
        """This plant as :func:`clm_sim.kernel.plant_step` takes it at sample time ``ts`` (s)."""
        h, ad, bd = self.substep_matrices(ts)
        return KernelPlant(h=h, substeps=self.substeps, ad=ad, bd=bd, mass=float(self.mass),
                           viscous=float(self.viscous), coulomb=float(self.coulomb),
                           stiffness=float(self.stiffness),
                           effects=lower_effects(self.effects).arrays())
