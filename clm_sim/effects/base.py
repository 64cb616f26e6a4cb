"""The contract every force effect keeps (:class:`Effect`: its law, regressor columns and
simulator terms) and the primitive terms of the compiled simulator (:class:`KernelTerms`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import ClassVar, NamedTuple

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

    def arrays(self) -> EffectArrays:
        """The terms as the compiled simulator takes them: contiguous float64 arrays, by name."""
        f = lambda x: np.ascontiguousarray(np.asarray(x, dtype=np.float64).reshape(-1))  # noqa: E731
        return EffectArrays(
            harmonic_amp=f(self.harmonic_amp), harmonic_k=f(self.harmonic_k),
            harmonic_phase=f(self.harmonic_phase),
            ripple_amp=f(self.ripple_amp), ripple_k=f(self.ripple_k),
            ripple_phase=f(self.ripple_phase),
            poly_coef=f(self.poly_coef if self.poly_coef else [0.0]),
            poly_center=float(self.poly_center), offset=float(self.offset),
            stribeck_peak=f(self.stribeck_peak), stribeck_velocity=f(self.stribeck_velocity),
            stribeck_exponent=f(self.stribeck_exponent), asym=f(self.asym),
            track=np.ascontiguousarray(np.column_stack([
                self.track_start, self.track_length, self.track_fringe]).reshape(-1, 3)),
            taut=np.ascontiguousarray(np.column_stack([
                self.taut_force, self.taut_reach, self.taut_center]).reshape(-1, 3)),
            dahl_sliding=f(self.dahl_sliding), dahl_length=f(self.dahl_length),
            dahl_state=np.zeros(len(self.dahl_sliding)),  # relaxed at the start
        )


class EffectArrays(NamedTuple):
    """:class:`KernelTerms` as the compiled simulator (:mod:`clm_sim.kernel`) reads them, each
    by its name: float64 arrays (``track`` and ``taut`` with one row of three per element:
    start, coil length, fringe; force, reach, centre) and two floats. ``dahl_state``: the
    pre-sliding elements' bristle states, advanced in place by a simulation."""

    harmonic_amp: np.ndarray
    harmonic_k: np.ndarray
    harmonic_phase: np.ndarray
    ripple_amp: np.ndarray
    ripple_k: np.ndarray
    ripple_phase: np.ndarray
    poly_coef: np.ndarray
    poly_center: float
    offset: float
    stribeck_peak: np.ndarray
    stribeck_velocity: np.ndarray
    stribeck_exponent: np.ndarray
    asym: np.ndarray
    track: np.ndarray
    taut: np.ndarray
    dahl_sliding: np.ndarray
    dahl_length: np.ndarray
    dahl_state: np.ndarray


def check_positive(where: str, **values: float) -> None:
    for key, value in values.items():
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise UserError(f"{where}: {key} must be a finite number > 0, got {value!r}")


def check_finite(where: str, **values: float) -> None:
    for key, value in values.items():
        if not (isinstance(value, (int, float)) and math.isfinite(value)):
            raise UserError(f"{where}: {key} must be a finite number, got {value!r}")


def amplitude_phase(c_sin: float, c_cos: float) -> tuple[float, float]:
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
    # (column, parameter) of an effect whose force is that parameter times a shape: its column
    # is its law with the parameter at 1 (exact: 1.0*x is x), its coefficient that parameter
    gain: ClassVar[tuple[str, str] | None] = None

    def law(self, y, v, u, xp):
        """The force (N) at position ``y`` (m), velocity ``v`` (m/s) and the rest of the force
        ``u`` (N), in the array namespace ``xp`` (:mod:`clm_sim.namespace`)."""
        raise NotImplementedError(f"effect {self.type!r} has no law of (y, v, u)")

    def force(self, y: np.ndarray, v: np.ndarray, u: np.ndarray) -> np.ndarray:
        """The law on numpy arrays (float64)."""
        return self.law(np.asarray(y), np.asarray(v), np.asarray(u), NUMPY)

    def regressors(self, y: np.ndarray, v: np.ndarray, u: np.ndarray) -> dict[str, np.ndarray]:
        """The columns it contributes to a linear-in-the-parameters model, by name."""
        if self.gain is None:
            raise NotImplementedError
        column, parameter = self.gain
        return {column: replace(self, **{parameter: 1.0}).force(y, v, u)}

    def from_coefficients(self, coef: dict[str, float]) -> "Effect":
        """The effect whose linear parameters are the least-squares coefficients ``coef`` of
        its columns (its nonlinear ones kept)."""
        if self.gain is None:
            raise NotImplementedError
        column, parameter = self.gain
        return replace(self, **{parameter: float(coef[column])})

    def lower(self, terms: KernelTerms) -> None:
        raise NotImplementedError

    def parameters(self) -> dict[str, float]:
        """Named parameters in SI units, as a config or a report writes them."""
        return {k: v for k, v in self.__dict__.items()}

    def as_config(self) -> dict:
        return {"type": self.type, **{k: (list(v) if isinstance(v, tuple) else v)
                                      for k, v in self.parameters().items()}}
