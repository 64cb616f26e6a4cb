"""Friction beyond the plant's viscous and Coulomb terms: the Stribeck curve at low speed,
pre-sliding (Dahl) friction along the position path, and friction that differs per direction."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from clm_sim.effects.base import Effect, check_finite, check_positive
from clm_sim.errors import UserError


@dataclass(frozen=True)
class Stribeck(Effect):
    """Low-speed friction curve: ``sign(v)*peak*exp(-(|v|/velocity)**exponent)`` on top of Coulomb.

    ``peak`` (N) is the rise *above* the Coulomb level, so the static (breakaway) friction is
    ``coulomb + peak``; ``velocity`` (m/s) is the Stribeck velocity; ``exponent`` is usually 2.
    (Called ``static`` before; renamed because the literature's static friction is the total.)
    A negative ``peak`` is a *dip*: friction below the Coulomb level at low speed that rises to
    it over ``velocity`` (velocity-strengthening friction, as a lubricant film or a preloaded
    nut can give); the plant keeps ``coulomb + peak >= 0``.
    """

    peak: float = 2.0
    velocity: float = 0.002
    exponent: float = 2.0
    type: ClassVar[str] = "stribeck"
    nonlinear: ClassVar[tuple[str, ...]] = ("velocity",)
    gain: ClassVar[tuple[str, str]] = ("stribeck", "peak")

    def __post_init__(self):
        check_finite("stribeck", peak=self.peak)
        check_positive("stribeck", velocity=self.velocity, exponent=self.exponent)

    def law(self, y, v, u, xp):
        return self.peak * xp.sign(v) * xp.exp(-((xp.abs(v) / self.velocity) ** self.exponent))

    def lower(self, terms):
        terms.stribeck_peak.append(self.peak)
        terms.stribeck_velocity.append(self.velocity)
        terms.stribeck_exponent.append(self.exponent)


def dahl_path(y, length: float) -> np.ndarray:
    """Normalised Dahl state ``z`` (-1..1) along the position path ``y`` (m), from ``z = 0``.

    ``dz/dy = (1 - sign(dy)*z)/length`` integrated exactly between samples (the path is taken as
    monotone between two samples): ``z1 = s - (s - z0)*exp(-|dy|/length)``, ``s = sign(dy)``.
    Rate-independent: the same path sampled at 1 kHz or 10 kHz gives the same state.
    """
    from clm_sim.kernel import dahl_states  # lazy: numba compiles on first use
    y = np.atleast_1d(np.asarray(y, dtype=np.float64))
    return dahl_states(np.ascontiguousarray(y.reshape(-1)), float(length)).reshape(y.shape)


@dataclass(frozen=True)
class Presliding(Effect):
    """Pre-sliding (Dahl) friction ``sliding*z``, with the bristle state ``z`` of :func:`dahl_path`.

    ``sliding`` (N): the friction it reaches in steady sliding (on top of the plant's ``coulomb``;
    a stage whose whole Coulomb friction is pre-sliding has ``coulomb = 0``). ``stiffness`` (N/m):
    the initial pre-sliding stiffness ``dF/dy`` at a reversal. Their ratio ``length`` (m) is the
    pre-sliding displacement scale: after a reversal the force has turned by 1 - 1/e of the
    way to the other side within ``2*length`` of travel. Dahl's model is LuGre without the
    Stribeck peak (a separate effect here) and without bristle damping, which makes the force a
    function of the position path alone.
    """

    sliding: float = 7.0
    stiffness: float = 2.0e6
    type: ClassVar[str] = "presliding"
    nonlinear: ClassVar[tuple[str, ...]] = ("length",)
    path_dependent: ClassVar[bool] = True

    def __post_init__(self):
        check_finite("presliding", sliding=self.sliding)
        check_positive("presliding", stiffness=self.stiffness)
        if self.sliding < 0:
            raise UserError(f"presliding: sliding must be >= 0 N, got {self.sliding!r}")

    @property
    def length(self) -> float:
        """Pre-sliding length ``sliding/stiffness`` (m); the template's when sliding is 0."""
        return self.sliding / self.stiffness if self.sliding > 0 else 1.0 / self.stiffness

    @classmethod
    def with_length(cls, sliding: float, length: float) -> Presliding:
        return cls(sliding=sliding, stiffness=(sliding if sliding > 0 else 1.0) / length)

    def force(self, y, v, u):
        return self.sliding * dahl_path(y, self.length)

    def regressors(self, y, v, u):
        return {"presliding": dahl_path(y, self.length)}

    def from_coefficients(self, coef):
        return Presliding.with_length(max(float(coef["presliding"]), 0.0), self.length)

    def lower(self, terms):
        if self.sliding > 0:
            terms.dahl_sliding.append(self.sliding)
            terms.dahl_length.append(self.length)


@dataclass(frozen=True)
class FrictionAsymmetry(Effect):
    """Extra friction per direction of motion, on top of the plant's symmetric ``fc`` and ``fv``.

    Moving in +y the motor supplies ``coulomb_pos + viscous_pos*v`` more; moving in -y it supplies
    ``-coulomb_neg + viscous_neg*v`` more (N and N*s/m). At rest the breakaway force grows by
    ``coulomb_pos`` (pushing +) or ``coulomb_neg`` (pushing -).
    """

    coulomb_pos: float = 0.0
    coulomb_neg: float = 0.0
    viscous_pos: float = 0.0
    viscous_neg: float = 0.0
    type: ClassVar[str] = "friction_asymmetry"

    def __post_init__(self):
        check_finite("friction_asymmetry", coulomb_pos=self.coulomb_pos,
                      coulomb_neg=self.coulomb_neg, viscous_pos=self.viscous_pos,
                      viscous_neg=self.viscous_neg)

    def law(self, y, v, u, xp):
        return xp.where(v > 0, self.coulomb_pos + self.viscous_pos * v,
                        xp.where(v < 0, -xp.const(self.coulomb_neg) + self.viscous_neg * v,
                                 xp.full_like(v, 0.0)))

    def regressors(self, y, v, u):
        # Only the part a LIP with fc*sign(v) and fv*v cannot absorb is identifiable: the
        # direction-odd terms |sign v| (Coulomb, (c_pos - c_neg)/2) and |v| (viscous,
        # (v_pos - v_neg)/2). During motion |sign v| = 1, so the Coulomb part equals a constant
        # force (ForceOffset); only standstill samples (v = 0) tell the two apart.
        v = np.asarray(v)
        return {"asym_coulomb": np.abs(np.sign(v)), "asym_viscous": np.abs(v)}

    def from_coefficients(self, coef):
        """The antisymmetric effect with those coefficients (its symmetric part is fc, fv)."""
        c, d = coef.get("asym_coulomb", 0.0), coef.get("asym_viscous", 0.0)
        return FrictionAsymmetry(coulomb_pos=c, coulomb_neg=-c, viscous_pos=d, viscous_neg=-d)

    def lower(self, terms):
        terms.asym = [a + b for a, b in zip(terms.asym, (self.coulomb_pos, self.coulomb_neg,
                                                         self.viscous_pos, self.viscous_neg))]
