"""The vocabulary of physical force effects, shared by the simulator, the models and the diagnosis.

Each effect is a small frozen dataclass with named SI parameters. It knows three things:

* ``law(y, v, u, xp)``: the force (N) it adds to what the motor must supply, in the inverse-model
  sign convention ``u = m*a + fv*v + fc*sign(v) + fk*y + sum(effect.force)``, written once against
  an array namespace ``xp`` (:mod:`clm_sim.namespace`): ``force(y, v, u)`` is the law on numpy
  arrays, and the export writes the same law as C and as ONNX nodes, so that a new effect exports
  with no edit to ``controllers/export/``. In the plant the force enters with the opposite sign
  (``m*a = u - ... - sum(effect.force)``);
* ``regressors(y, v, u)``: the columns it contributes to a linear-in-the-parameters model when its
  nonlinear parameters (periods, velocities) are held fixed, and ``from_coefficients`` to rebuild the
  effect from the least-squares coefficients of those columns;
* ``lower(terms)``: how it appears in the compiled simulator, as primitive terms of
  :class:`KernelTerms` (position harmonics, motor-force ripple and the track end's motor-force
  factor, a position polynomial, Stribeck friction, direction-dependent friction, a constant
  force, Dahl pre-sliding friction, a taut cable carrier's saturating pull). The
  simulator keeps this lowering of its own: it integrates the *forward* plant, where friction at
  rest is stiction up to the breakaway level (not the law's value at ``v = 0``) and the ripple
  multiplies the motor force, in a numba kernel compiled once for these fixed term arrays (a law
  compiled per model would cost a compilation per plant); the tests hold the kernel's forces in
  motion to the laws.

Most forces are functions of the instantaneous ``(y, v, u)``. Pre-sliding friction has a state
(the bristle deflection), but Dahl's state is a function of the position *path* alone, so its
``force`` and ``regressors`` read ``y`` as an ordered path (a record's samples, any sample rate).

``EFFECTS`` maps a config ``type:`` to its class; it is the only place names are resolved.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from clm_sim.errors import UserError
from clm_sim.namespace import NUMPY


@dataclass
class KernelTerms:
    """Primitive force terms the compiled simulator understands, as float64 arrays.

    ``harmonic_*``: additive position-periodic forces ``amp*sin(k*y + phase)`` (N, rad/m, rad).
    ``ripple_*``: motor-force modulation, motor force ``u*(1 + sum amp*sin(k*y + phase))``.
    ``poly_coef``: additive ``sum c_i*(y - poly_center)**i`` (N/m**i), ``i = 0..len-1``.
    ``stribeck_*``: ``sign(v)*peak*exp(-(|v|/velocity)**exponent)`` (N, m/s, -).
    ``asym``: extra friction per direction ``[coulomb_pos, coulomb_neg, viscous_pos, viscous_neg]``.
    ``offset``: a constant force (N).
    ``track_*``: motor-force factors ``g(y)`` of :class:`TrackEnd` (start, coil length, fringe,
    m); the motor force is ``u*(1 + ripple)*prod g``.
    ``taut_*``: additive ``force*tanh(((y - center)/reach)**3)`` of :class:`CableTaut` (N, m, m).
    """

    harmonic_amp: list = field(default_factory=list)
    harmonic_k: list = field(default_factory=list)
    harmonic_phase: list = field(default_factory=list)
    ripple_amp: list = field(default_factory=list)
    ripple_k: list = field(default_factory=list)
    ripple_phase: list = field(default_factory=list)
    poly_coef: list = field(default_factory=list)
    poly_center: float = 0.0
    stribeck_peak: list = field(default_factory=list)
    stribeck_velocity: list = field(default_factory=list)
    stribeck_exponent: list = field(default_factory=list)
    asym: list = field(default_factory=lambda: [0.0, 0.0, 0.0, 0.0])
    offset: float = 0.0
    dahl_sliding: list = field(default_factory=list)
    dahl_length: list = field(default_factory=list)
    track_start: list = field(default_factory=list)
    track_length: list = field(default_factory=list)
    track_fringe: list = field(default_factory=list)
    taut_force: list = field(default_factory=list)
    taut_reach: list = field(default_factory=list)
    taut_center: list = field(default_factory=list)

    def arrays(self) -> tuple:
        """The terms as contiguous float64 arrays, in the order the kernel takes them."""
        f = lambda x: np.ascontiguousarray(np.asarray(x, dtype=np.float64).reshape(-1))  # noqa: E731
        return (
            f(self.harmonic_amp), f(self.harmonic_k), f(self.harmonic_phase),
            f(self.ripple_amp), f(self.ripple_k), f(self.ripple_phase),
            f(self.poly_coef if self.poly_coef else [0.0]), float(self.poly_center),
            float(self.offset),
            f(self.stribeck_peak), f(self.stribeck_velocity), f(self.stribeck_exponent),
            f(self.asym),
            np.ascontiguousarray(np.column_stack([self.track_start, self.track_length,
                                                  self.track_fringe]).reshape(-1, 3)),
            np.ascontiguousarray(np.column_stack([self.taut_force, self.taut_reach,
                                                  self.taut_center]).reshape(-1, 3)),
            f(self.dahl_sliding), f(self.dahl_length),
            np.zeros(len(self.dahl_sliding)),  # the bristle states (relaxed at the start)
        )


def _check_positive(where: str, **values: float) -> None:
    for key, value in values.items():
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise UserError(f"{where}: {key} must be a finite number > 0, got {value!r}")


def _check_finite(where: str, **values: float) -> None:
    for key, value in values.items():
        if not (isinstance(value, (int, float)) and math.isfinite(value)):
            raise UserError(f"{where}: {key} must be a finite number, got {value!r}")


def _amplitude_phase(c_sin: float, c_cos: float) -> tuple[float, float]:
    """``a*sin(x) + b*cos(x) = A*sin(x + phi)``; returns ``(A, phi)`` with ``A >= 0``."""
    return float(math.hypot(c_sin, c_cos)), float(math.atan2(c_cos, c_sin))


@dataclass(frozen=True)
class Effect:
    """Base of all effects; subclasses set ``type`` and ``nonlinear`` (parameters a search must find)."""

    type: ClassVar[str] = ""
    nonlinear: ClassVar[tuple[str, ...]] = ()
    aliases: ClassVar[dict[str, str]] = {}  # config name -> field name, where a field would clash
    # True where the force is a function of the whole position path (a state), not of the
    # instant's (y, v, u): no law, no window form, not exportable
    path_dependent: ClassVar[bool] = False
    # True where no linear-in-parameters model has a column for it (the simulated plant only)
    plant_only: ClassVar[bool] = False

    def law(self, y, v, u, xp):
        """The force (N) at position ``y`` (m), velocity ``v`` (m/s) and the rest of the force
        ``u`` (N), in the array namespace ``xp`` (:mod:`clm_sim.namespace`)."""
        raise NotImplementedError(f"effect {self.type!r} has no law of (y, v, u)")

    def force(self, y: np.ndarray, v: np.ndarray, u: np.ndarray) -> np.ndarray:
        """The law on numpy arrays (float64)."""
        return self.law(np.asarray(y), np.asarray(v), np.asarray(u), NUMPY)

    def regressors(self, y: np.ndarray, v: np.ndarray, u: np.ndarray) -> dict[str, np.ndarray]:
        raise NotImplementedError

    def from_coefficients(self, coef: dict[str, float]) -> "Effect":
        raise NotImplementedError

    def lower(self, terms: KernelTerms) -> None:
        raise NotImplementedError

    def parameters(self) -> dict[str, float]:
        """Named parameters in SI units, as a config or a report writes them."""
        return {k: v for k, v in self.__dict__.items()}

    def as_config(self) -> dict:
        return {"type": self.type, **{k: (list(v) if isinstance(v, tuple) else v)
                                      for k, v in self.parameters().items()}}


@dataclass(frozen=True)
class Cogging(Effect):
    """Position-periodic force from magnet/iron attraction: ``amplitude*sin(2*pi*y/period + phase)``.

    amplitude in N, period in m (the magnet pitch or a fraction of it), phase in rad.
    """

    amplitude: float = 1.0
    period: float = 0.016
    phase: float = 0.0
    type: ClassVar[str] = "cogging"
    nonlinear: ClassVar[tuple[str, ...]] = ("period",)

    def __post_init__(self):
        _check_finite("cogging", amplitude=self.amplitude, phase=self.phase)
        _check_positive("cogging", period=self.period)

    def _arg(self, y):
        return 2.0 * np.pi * np.asarray(y) / self.period

    def law(self, y, v, u, xp):
        return self.amplitude * xp.sin(2.0 * xp.pi * y / self.period + self.phase)

    def regressors(self, y, v, u):
        x = self._arg(y)
        return {"cogging_sin": np.sin(x), "cogging_cos": np.cos(x)}

    def from_coefficients(self, coef):
        amp, phase = _amplitude_phase(coef["cogging_sin"], coef["cogging_cos"])
        return Cogging(amplitude=amp, period=self.period, phase=phase)

    def lower(self, terms):
        terms.harmonic_amp.append(self.amplitude)
        terms.harmonic_k.append(2.0 * math.pi / self.period)
        terms.harmonic_phase.append(self.phase)


@dataclass(frozen=True)
class ForceRipple(Effect):
    """Commutation ripple: the motor delivers ``u*(1 + amplitude*sin(2*pi*y/period + phase))``.

    amplitude is a fraction of the commanded force (0.01 = 1 %), period in m, phase in rad. The
    motor must then supply about ``-amplitude*sin(...)*u`` extra, which is ``force``.
    """

    amplitude: float = 0.01
    period: float = 0.032
    phase: float = 0.0
    type: ClassVar[str] = "force_ripple"
    nonlinear: ClassVar[tuple[str, ...]] = ("period",)

    def __post_init__(self):
        _check_finite("force_ripple", amplitude=self.amplitude, phase=self.phase)
        _check_positive("force_ripple", period=self.period)
        if not abs(self.amplitude) < 0.5:
            raise UserError(f"force_ripple: amplitude is a fraction of the motor force and must be "
                            f"below 0.5, got {self.amplitude!r}")

    def _arg(self, y):
        return 2.0 * np.pi * np.asarray(y) / self.period

    def law(self, y, v, u, xp):
        # Exact inverse of u_motor = u*(1+rho): u = rest/(1+rho) = rest - rho*u.
        return -xp.const(self.amplitude) * xp.sin(2.0 * xp.pi * y / self.period + self.phase) * u

    def regressors(self, y, v, u):
        x = self._arg(y)
        return {"ripple_sin": -np.asarray(u) * np.sin(x), "ripple_cos": -np.asarray(u) * np.cos(x)}

    def from_coefficients(self, coef):
        amp, phase = _amplitude_phase(coef["ripple_sin"], coef["ripple_cos"])
        return ForceRipple(amplitude=amp, period=self.period, phase=phase)

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
        _check_positive("track_end", start=self.start, coil_length=self.coil_length,
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
        _check_finite("cable_slab", center=self.center,
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

    def __post_init__(self):
        _check_finite("cable_taut", pull=self.pull, center=self.center)
        _check_positive("cable_taut", reach=self.reach)

    def law(self, y, v, u, xp):
        return self.pull * xp.tanh(((y - self.center) / self.reach) ** 3)

    def regressors(self, y, v, u):
        return {"cable_taut": np.tanh(((np.asarray(y) - self.center) / self.reach) ** 3)}

    def from_coefficients(self, coef):
        return CableTaut(pull=float(coef["cable_taut"]), reach=self.reach, center=self.center)

    def lower(self, terms):
        terms.taut_force.append(self.pull)
        terms.taut_reach.append(self.reach)
        terms.taut_center.append(self.center)


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

    def __post_init__(self):
        _check_finite("stribeck", peak=self.peak)
        _check_positive("stribeck", velocity=self.velocity, exponent=self.exponent)

    def _shape(self, v):
        v = np.asarray(v)
        return np.sign(v) * np.exp(-((np.abs(v) / self.velocity) ** self.exponent))

    def law(self, y, v, u, xp):
        return self.peak * xp.sign(v) * xp.exp(-((xp.abs(v) / self.velocity) ** self.exponent))

    def regressors(self, y, v, u):
        return {"stribeck": self._shape(v)}

    def from_coefficients(self, coef):
        return Stribeck(peak=float(coef["stribeck"]), velocity=self.velocity,
                        exponent=self.exponent)

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
        _check_finite("presliding", sliding=self.sliding)
        _check_positive("presliding", stiffness=self.stiffness)
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
        _check_finite("friction_asymmetry", coulomb_pos=self.coulomb_pos,
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


@dataclass(frozen=True)
class ForceOffset(Effect):
    """A constant force the motor must supply (N): gravity on a tilted axis, a cable preload, an
    amplifier offset."""

    force_n: float = 0.0
    type: ClassVar[str] = "force_offset"
    aliases: ClassVar[dict[str, str]] = {"force": "force_n"}

    def __post_init__(self):
        _check_finite("force_offset", force_n=self.force_n)

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


EFFECTS: dict[str, type[Effect]] = {
    cls.type: cls for cls in (Cogging, ForceRipple, CableSlab, CableTaut, Stribeck,
                              FrictionAsymmetry, ForceOffset, Presliding, TrackEnd)
}
"""The effect classes by their config ``type:`` (the one place names are resolved).

A config's ``effects:`` entry ``{type: cogging, amplitude: 3, ...}`` is
``EFFECTS["cogging"](amplitude=3, ...)``; each class is a frozen dataclass with named SI
parameters, its force law, its regressor columns and its simulator terms.

Examples
--------
>>> from clm_sim import EFFECTS
>>> sorted(EFFECTS)  # doctest: +NORMALIZE_WHITESPACE
['cable_slab', 'cable_taut', 'cogging', 'force_offset', 'force_ripple', 'friction_asymmetry',
 'presliding', 'stribeck', 'track_end']
>>> cogging = EFFECTS["cogging"](amplitude=3.0, period=0.016)
>>> cogging.as_config()
{'type': 'cogging', 'amplitude': 3.0, 'period': 0.016, 'phase': 0.0}
>>> float(cogging.force(0.004, 0.0, 0.0))  # N at y = 4 mm: a quarter period
3.0
"""


def lower_effects(effects) -> KernelTerms:
    """Collect the kernel terms of a sequence of effects."""
    terms = KernelTerms()
    for effect in effects:
        effect.lower(terms)
    return terms


def total_force(effects, y, v, u) -> np.ndarray:
    """Sum of the effects' forces (N, inverse-model sign), vectorised over samples."""
    out = np.zeros(np.shape(y), dtype=float)
    for effect in effects:
        out = out + effect.force(y, v, u)
    return out
