"""PGNN settings: the network and optimizer options of a PGNN feedforward, declared once (types,
ranges, defaults) for the config, the testbed and :class:`controllers.pgnn.PGNNFeedforward`."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from clm_sim.errors import UserError


@dataclass(frozen=True)
class PGNNSettings:
    """Network and optimizer settings of a PGNN feedforward (see controllers.pgnn).

    init: optimized (the lemma's least squares) or random; max_iter: LM iterations (Jacobian
    evaluations) or Adam steps; optimizer: lm or adam; adam_lr: Adam step size;
    validation_fraction: last part of the data held out to pick the best iterate (0: none);
    pinn_weight: weight of the PINN term (training pinn only); lambda_diag: per-parameter
    regularization weights (mass, viscous, coulomb, stiffness; physical units) overriding lambda;
    decimation: keep every n-th sample of the filtered training data.
    """

    init: Literal["optimized", "random"] = "optimized"
    max_iter: int = 100
    optimizer: Literal["lm", "adam"] = "lm"
    adam_lr: float = 1e-3
    validation_fraction: float = 0.0
    pinn_weight: float = 1.0
    lambda_diag: dict[str, float] | None = None
    decimation: int = 20

    def __post_init__(self):
        if not (isinstance(self.max_iter, int) and self.max_iter >= 1):
            raise UserError(f"pgnn.max_iter: expected an integer >= 1, got {self.max_iter!r}")
        if not (isinstance(self.decimation, int) and self.decimation >= 1):
            raise UserError(f"pgnn.decimation: expected an integer >= 1, got {self.decimation!r}")
        if not 0.0 <= self.validation_fraction < 0.5:
            raise UserError(f"pgnn.validation_fraction: expected a number in [0, 0.5), "
                            f"got {self.validation_fraction!r}")
        if not self.pinn_weight >= 0 or not self.adam_lr > 0:
            raise UserError("pgnn: pinn_weight must be >= 0 and adam_lr > 0")
        for k, v in (self.lambda_diag or {}).items():
            if k not in ("mass", "viscous", "coulomb", "stiffness") or not v >= 0:
                raise UserError(f"pgnn.lambda_diag.{k}: expected one of mass, viscous, coulomb, "
                                f"stiffness with a weight >= 0, got {v!r}")
