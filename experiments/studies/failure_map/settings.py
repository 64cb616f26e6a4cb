"""The ``failure_map:`` section of a study config (:mod:`experiments.studies.failure_map.study`):
the cases, directions, network sizes, lambda and seeds of the map, strictly typed."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

from clm_sim.effects.base import Effect
from clm_sim.effects.friction import Stribeck
from clm_sim.effects.position import CableSlab, Cogging, ForceRipple
from clm_sim.errors import UserError
from controllers.pgnn_settings import FILE_KEYS, PGNNSettings


def _default_cases() -> dict[str, tuple[Effect, ...]]:
    # The sizes are argued in experiments/configs/failure_map.yaml.
    return {
        "none": (),
        "cable_carrier": (CableSlab(coefficients=(0.0, 10.0, 0.0, 2000.0), center=0.0),),
        "cogging": (Cogging(amplitude=1.0, period=0.012, phase=0.0),),
        "force_ripple": (ForceRipple(amplitude=0.01, period=0.024, phase=0.0),),
        "stribeck": (Stribeck(peak=1.0, velocity=0.001, exponent=2.0),),
    }


@dataclass(frozen=True)
class FailureMapSettings:
    """The ``failure_map:`` section of a config.

    cases: name -> the parasitic effects of the plant in that case (they replace
    ``plant.effects``; ``[]`` is the plant without any); outside: direction of extrapolation ->
    the reference that leaves the training range that way; inside: the training reference
    (reported for context); hidden: network sizes n_l; lam: the regularization weight compared
    with lambda = 0 (physical units, > 0); seeds: paired seeds per cell (>= 2 for an interval);
    confidence: level of the intervals; pgnn: network and optimizer settings shared by every fit.
    """

    cases: dict[str, tuple[Effect, ...]] = field(default_factory=_default_cases)
    outside: dict[str, str] = field(
        default_factory=lambda: {"position": "r2", "velocity": "r3"})
    inside: str = "r1"
    hidden: tuple[int, ...] = (8, 32)
    lam: float = 0.01
    seeds: int = 10
    confidence: float = 0.95
    pgnn: PGNNSettings = field(default_factory=PGNNSettings)
    aliases: ClassVar[dict[str, str]] = {FILE_KEYS["lam"]: "lam"}  # config -> field

    def __post_init__(self):
        if not self.cases:
            raise UserError("cases: expected at least one case")
        if not self.outside:
            raise UserError("outside: expected at least one direction: reference")
        for direction, key in self.outside.items():
            if key == self.inside:
                raise UserError(f"outside.{direction}: {key!r} is the inside reference; an "
                                f"outside reference leaves the training range")
        if not self.hidden or any(h < 1 for h in self.hidden) or len(set(self.hidden)) < len(
                self.hidden):
            raise UserError(f"hidden: expected distinct integers >= 1, got {list(self.hidden)}")
        if not self.lam > 0:
            raise UserError(f"lambda: expected a number > 0 (compared with lambda = 0), "
                            f"got {self.lam!r}")
        if not (isinstance(self.seeds, int) and self.seeds >= 2):
            raise UserError(f"seeds: expected an integer >= 2 (a paired interval needs two), "
                            f"got {self.seeds!r}")
        if not 0.5 <= self.confidence < 1:
            raise UserError(f"confidence: expected a level in [0.5, 1), got {self.confidence!r}")
