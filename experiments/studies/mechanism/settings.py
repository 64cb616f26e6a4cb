"""The ``mechanism:`` section of a study config (:mod:`experiments.studies.mechanism.study`):
its settings, checked once, and the loader of a mechanism config."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

from clm_sim.effects.base import Effect
from clm_sim.effects.position import CableSlab
from clm_sim.errors import UserError
from controllers.pgnn_settings import FILE_KEYS, PerParameter, PGNNSettings
from experiments.config import ExperimentConfig
from experiments.studies.kinds import load_case_study


def _default_cases() -> dict[str, tuple[Effect, ...]]:
    return {"cable_cubic": (CableSlab(coefficients=(0.0, 10.0, 0.0, 2000.0)),),
            "cable_linear": (CableSlab(coefficients=(0.0, 10.0)),)}


@dataclass(frozen=True)
class MechanismSettings:
    """The ``mechanism:`` section of a config.

    cases: name -> the parasitic effects of the plant (they replace ``plant.effects``);
    records: training records (dither seeds) per case, >= 2; draws: network draws per record,
    >= 1; hidden: n_l; lam: the lambda compared with 0 (> 0); inside / outside: the training
    reference and the one that leaves its range; pgnn: the fit settings shared by both rows
    (default: the paper's cost); bootstrap: resamples of the two-level bootstrap; confidence:
    level of the intervals; grid_points: positions of the static force curve; zero_lam_diag
    (``lambda0_diag:`` in a config): per-parameter pulls toward theta_LIP given to the lambda = 0
    row only, e.g. ``{stiffness: 0.01}``: that row then holds those parameters and leaves the rest
    free, a control that acts on one parameter's drift and keeps the plant (None: none);
    near_linear: the unit-by-unit view and its intervention
    (:mod:`experiments.studies.mechanism.units`): a hidden unit whose pre-activation stays within
    +-near_linear on the training samples is near-linear (None: no view); prediction: per case, the
    numbers written before the run (:mod:`experiments.studies.mechanism.prediction`:
    ``mae_diff_um``, ``error_beyond_lambda0_n``, ``error_beyond_lambda_n``, and ``factor``, how far
    the measured amount may lie from the predicted one), which the report sets beside the outcome.
    """

    cases: dict[str, tuple[Effect, ...]] = field(default_factory=_default_cases)
    records: int = 5
    draws: int = 2
    hidden: int = 16
    lam: float = 0.01
    inside: str = "r1"
    outside: str = "r2"
    pgnn: PGNNSettings = field(default_factory=lambda: PGNNSettings(
        weight_decay=0.0, continuation_lam=0.0))
    bootstrap: int = 4000
    confidence: float = 0.95
    grid_points: int = 69
    zero_lam_diag: dict[str, float] | None = None
    near_linear: float | None = None
    prediction: dict[str, dict[str, float]] | None = None
    aliases: ClassVar[dict[str, str]] = {FILE_KEYS["lam"]: "lam",  # config -> field
                                         "lambda0_diag": "zero_lam_diag"}

    def __post_init__(self):
        if not self.cases:
            raise UserError("cases: expected at least one case")
        for key, low in (("records", 2), ("draws", 1), ("hidden", 1), ("bootstrap", 100),
                         ("grid_points", 11)):
            value = getattr(self, key)
            if not (isinstance(value, int) and not isinstance(value, bool) and value >= low):
                raise UserError(f"{key}: expected an integer >= {low}, got {value!r}")
        if not self.lam > 0:
            raise UserError(f"lambda: expected a number > 0, got {self.lam!r}")
        if not 0.5 <= self.confidence < 1:
            raise UserError(f"confidence: expected a level in [0.5, 1), got {self.confidence!r}")
        if self.zero_lam_diag is not None:
            if not PerParameter().accepts(self.zero_lam_diag) or not any(
                    v > 0 for v in self.zero_lam_diag.values()):
                raise UserError(f"lambda0_diag: expected {PerParameter().describe()}, one of "
                                f"them > 0, got {self.zero_lam_diag!r}")
            # A pull on the lambda = 0 row also turns its continuation start off (it runs only
            # without one): with a start on, the rows would differ in two settings.
            if self.pgnn.continuation_lam > 0:
                raise UserError(f"lambda0_diag: needs pgnn.continuation_lambda: 0 (got "
                                f"{self.pgnn.continuation_lam:g}); with a continuation start "
                                f"the held row would differ in two settings")
        if self.near_linear is not None and not (
                isinstance(self.near_linear, (int, float)) and self.near_linear > 0):
            raise UserError(f"near_linear: expected a number > 0, got {self.near_linear!r}")
        for case, p in (self.prediction or {}).items():
            if case not in self.cases:
                raise UserError(f"prediction.{case}: not a case (cases: {', '.join(self.cases)})")
            missing = {"mae_diff_um", "error_beyond_lambda0_n", FILE_KEYS["error_beyond_lam_n"],
                       "factor"} - set(p)
            if missing:
                raise UserError(f"prediction.{case}: expected the keys "
                                f"{', '.join(sorted(missing))}")
            if not p["factor"] > 1:
                raise UserError(f"prediction.{case}.factor: expected a number > 1, got "
                                f"{p['factor']!r}")
        if self.outside == self.inside:
            raise UserError(f"outside: {self.inside!r} is the inside reference; an outside "
                            f"reference leaves the training range")


def load_mechanism(path) -> tuple[ExperimentConfig, MechanismSettings]:
    """Read a mechanism config; errors name the file and the key."""
    return load_case_study(path, "mechanism", "mechanism", MechanismSettings,
                           lambda settings: (settings.inside, settings.outside))
