"""Forces of the position: cogging, commutation ripple, the coil leaving the magnet track, the
cable carrier (a polynomial, or a pull that saturates once taut), and a constant force."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np

from clm_sim.effects.base import Effect, amplitude_phase, check_finite, check_positive
from clm_sim.errors import UserError
from clm_sim.namespace import NUMPY


class _Harmonic:
    """The shape of a force periodic in the position: ``sin(angle + phase)`` with the angle
    ``2*pi*y/period`` (rad) written once, for the law and for the columns ``<column>_sin`` and
    ``<column>_cos`` of a linear fit (``carrier`` times ``sin(angle)`` and ``cos(angle)``), whose
    coefficients give the amplitude and the phase back."""

    column: ClassVar[str] = ""

    def angle(self, y, xp=NUMPY):
        """``2*pi*y/period`` (rad) at position ``y`` (m), in the array namespace ``xp``."""
        return 2.0 * xp.pi * y / self.period

    def wave(self, y, xp):
        """``sin(angle + phase)``, the shape the law scales."""
        return xp.sin(self.angle(y, xp) + self.phase)

    def harmonic_columns(self, y, carrier=None) -> dict[str, np.ndarray]:
        """``carrier*sin(angle)`` and ``carrier*cos(angle)`` (``carrier`` None: 1)."""
        x = self.angle(np.asarray(y))
        if carrier is None:
            return {f"{self.column}_sin": np.sin(x), f"{self.column}_cos": np.cos(x)}
        return {f"{self.column}_sin": carrier * np.sin(x),
                f"{self.column}_cos": carrier * np.cos(x)}

    def from_coefficients(self, coef):
        amp, phase = amplitude_phase(coef[f"{self.column}_sin"], coef[f"{self.column}_cos"])
        return replace(self, amplitude=amp, phase=phase)


@dataclass(frozen=True)
class Cogging(_Harmonic, Effect):
    """Position-periodic force from magnet/iron attraction: ``amplitude*sin(2*pi*y/period + phase)``.

    amplitude in N, period in m (the magnet pitch or a fraction of it), phase in rad.
    """

    amplitude: float = 1.0
    period: float = 0.016
    phase: float = 0.0
    type: ClassVar[str] = "cogging"
    nonlinear: ClassVar[tuple[str, ...]] = ("period",)
    column: ClassVar[str] = "cogging"

    def __post_init__(self):
        check_finite("cogging", amplitude=self.amplitude, phase=self.phase)
        check_positive("cogging", period=self.period)

    def law(self, y, v, u, xp):
        return self.amplitude * self.wave(y, xp)

    def regressors(self, y, v, u):
        return self.harmonic_columns(y)

    def lower(self, terms):
        terms.harmonic_amp.append(self.amplitude)
        terms.harmonic_k.append(2.0 * math.pi / self.period)
        terms.harmonic_phase.append(self.phase)


@dataclass(frozen=True)
class ForceRipple(_Harmonic, Effect):
    """Commutation ripple: the motor delivers ``u*(1 + amplitude*sin(2*pi*y/period + phase))``.

    amplitude is a fraction of the commanded force (0.01 = 1 %), period in m, phase in rad. The
    motor must then supply about ``-amplitude*sin(...)*u`` extra, which is ``force``.
    """

    amplitude: float = 0.01
    period: float = 0.032
    phase: float = 0.0
    type: ClassVar[str] = "force_ripple"
    nonlinear: ClassVar[tuple[str, ...]] = ("period",)
    column: ClassVar[str] = "ripple"

    def __post_init__(self):
        check_finite("force_ripple", amplitude=self.amplitude, phase=self.phase)
        check_positive("force_ripple", period=self.period)
        if not abs(self.amplitude) < 0.5:
            raise UserError(f"force_ripple: amplitude is a fraction of the motor force and must be "
                            f"below 0.5, got {self.amplitude!r}")

    def law(self, y, v, u, xp):
        # Exact inverse of u_motor = u*(1+rho): u = rest/(1+rho) = rest - rho*u.
        return -xp.const(self.amplitude) * self.wave(y, xp) * u

    def regressors(self, y, v, u):
        return self.harmonic_columns(y, carrier=-np.asarray(u))

    def lower(self, terms):
        terms.ripple_amp.append(self.amplitude)
        terms.ripple_k.append(2.0 * math.pi / self.period)
        terms.ripple_phase.append(self.phase)


def _softplus(x, xp):
    """``log(1 + e^x)`` without overflow: ``relu(x) + log1p(exp(-|x|))``."""
    return xp.relu(x) + xp.log1p(xp.exp(-xp.abs(x)))


@dataclass(frozen=True)
class TrackEnd(Effect):
    """The coil leaving the magnet track: the motor delivers ``u*g(y)``, with ``g`` the fraction of
    the coil that still overlaps the magnets (1 over the track, 0 off it).

    A coreless coil of length ``coil_length`` (m) centred at ``y`` overlaps magnets that end at
    ``+-(start + coil_length/2)``: from ``|y| = start`` (m) on, its force constant falls linearly
    with the lost overlap, to zero at ``|y| = start + coil_length``. The fringing field at the
    track's end rounds both corners: ``g`` is the hard overlap convolved with a logistic kernel
    of scale ``fringe`` (m), ``g = 1 - ramp(y - start) - ramp(-y - start)``,
    ``ramp(x) = fringe*(softplus(x/fringe) - softplus((x - coil_length)/fringe))/coil_length``.
    The motor must then supply ``(1 - g)*u`` more, which is ``force`` (exact with ``u`` the motor
    command: ``u*g = rest``).

    Plant-only: it has no regressor columns, so no identified feedforward (LIP, PGNN, diagnosis)
    carries it; its law exports like any other's.
    """

    start: float = 0.12
    coil_length: float = 0.12
    fringe: float = 0.004
    type: ClassVar[str] = "track_end"
    plant_only: ClassVar[bool] = True

    def __post_init__(self):
        check_positive("track_end", start=self.start, coil_length=self.coil_length,
                        fringe=self.fringe)
        if not self.fringe < 0.5 * self.coil_length:
            raise UserError(f"track_end: fringe must be below half the coil_length "
                            f"({0.5 * self.coil_length!r} m), got {self.fringe!r}")

    def _ramp(self, x, xp):
        w, length = self.fringe, self.coil_length
        return w * (_softplus(x / w, xp) - _softplus((x - length) / w, xp)) / length

    def overlap(self, y, xp=NUMPY):
        """The overlap fraction ``g(y)`` (-), the factor on the motor force at position ``y`` (m)."""
        return 1.0 - self._ramp(y - self.start, xp) - self._ramp(-y - self.start, xp)

    def law(self, y, v, u, xp):
        return (self._ramp(y - self.start, xp) + self._ramp(-y - self.start, xp)) * u

    def regressors(self, y, v, u):
        raise UserError("track_end is plant-only: a linear-in-parameters model has no column "
                        "for it")

    def lower(self, terms):
        terms.track_start.append(self.start)
        terms.track_length.append(self.coil_length)
        terms.track_fringe.append(self.fringe)


@dataclass(frozen=True)
class CableSlab(Effect):
    """Position-dependent force of the cable carrier: ``sum coefficients[i]*(y - center)**i``.

    ``coefficients`` in N/m**i for i = 0, 1, 2, ...; ``center`` in m (where the cable loop is
    relaxed). The constant and linear terms are what a LIP absorbs as offset and stiffness; the
    higher terms model the carrier's bending loop, whose force grows faster towards the stroke ends.
    """

    coefficients: tuple[float, ...] = (0.0, 10.0, 0.0, 2000.0)
    center: float = 0.0
    type: ClassVar[str] = "cable_slab"

    def __post_init__(self):
        object.__setattr__(self, "coefficients", tuple(float(c) for c in self.coefficients))
        if not self.coefficients:
            raise UserError("cable_slab: coefficients must hold at least one number")
        check_finite("cable_slab", center=self.center,
                      **{f"coefficients[{i}]": c for i, c in enumerate(self.coefficients)})

    def law(self, y, v, u, xp):
        x = y - self.center  # Horner's scheme, as numpy's polyval
        out = xp.full_like(x, self.coefficients[-1])
        for c in reversed(self.coefficients[:-1]):
            out = c + x * out
        return out

    def regressors(self, y, v, u):
        d = np.asarray(y) - self.center
        return {f"cable_{i}": d**i for i in range(2, len(self.coefficients))}

    def from_coefficients(self, coef):
        c = [0.0, 0.0] + [coef[f"cable_{i}"] for i in range(2, len(self.coefficients))]
        return CableSlab(coefficients=tuple(c), center=self.center)

    def lower(self, terms):
        if any(terms.poly_coef) and terms.poly_center != self.center:
            raise UserError("plant: two cable_slab effects need the same center")
        n = max(len(terms.poly_coef), len(self.coefficients))
        old = list(terms.poly_coef) + [0.0] * (n - len(terms.poly_coef))
        terms.poly_coef[:] = [a + b for a, b in zip(old, list(self.coefficients) + [0.0] * n)]
        terms.poly_center = self.center


@dataclass(frozen=True)
class CableTaut(Effect):
    """A cable carrier whose pull hardens as it is drawn out and stops growing once it is taut:
    ``pull*tanh(((y - center)/reach)**3)``.

    The chain's bending loop resists more the further the slide draws it (the force grows as the
    cube of the travel near ``center``, as :class:`CableSlab`'s cubic term), until the chain lies
    straight against its guide channel, whose end clamp then carries the tension: beyond about
    ``reach`` (m) the stage feels ``pull`` (N) and no more. The force is steepest at
    ``|y - center| = 0.849*reach`` (where ``x**3*tanh(x**3) = 1/3``): it hardens inside that and
    flattens beyond it. Near ``center`` it is ``(pull/reach**3)*(y - center)**3``.
    """

    pull: float = 3.27
    reach: float = 0.1178
    center: float = 0.0
    type: ClassVar[str] = "cable_taut"
    nonlinear: ClassVar[tuple[str, ...]] = ("reach",)
    gain: ClassVar[tuple[str, str]] = ("cable_taut", "pull")

    def __post_init__(self):
        check_finite("cable_taut", pull=self.pull, center=self.center)
        check_positive("cable_taut", reach=self.reach)

    def law(self, y, v, u, xp):
        return self.pull * xp.tanh(((y - self.center) / self.reach) ** 3)

    def lower(self, terms):
        terms.taut_force.append(self.pull)
        terms.taut_reach.append(self.reach)
        terms.taut_center.append(self.center)


@dataclass(frozen=True)
class ForceOffset(Effect):
    """A constant force the motor must supply (N): gravity on a tilted axis, a cable preload, an
    amplifier offset."""

    force_n: float = 0.0
    type: ClassVar[str] = "force_offset"
    aliases: ClassVar[dict[str, str]] = {"force": "force_n"}

    def __post_init__(self):
        check_finite("force_offset", force_n=self.force_n)

    def law(self, y, v, u, xp):
        return xp.full_like(y, self.force_n)

    def regressors(self, y, v, u):
        return {"offset": np.ones(np.shape(y))}

    def from_coefficients(self, coef):
        return ForceOffset(force_n=coef["offset"])

    def parameters(self):
        return {"force": self.force_n}

    def lower(self, terms):
        terms.offset += self.force_n
