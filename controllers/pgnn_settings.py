"""PGNN settings: the network and optimizer options of a PGNN feedforward, declared once (types,
ranges, defaults) for the config, the testbed and :class:`controllers.pgnn.PGNNFeedforward`."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from clm_sim.errors import UserError

TRAININGS = ("simultaneous", "sequential", "pinn")
OPTIMIZERS = ("varpro", "lm", "adam")
ACTIVATION_NAMES = ("tanh", "sigmoid", "softplus", "silu", "gelu", "relu")


@dataclass(frozen=True)
class PGNNSettings:
    """Network and optimizer settings of a PGNN feedforward (see controllers.pgnn).

    activation: of the hidden layers; init: optimized (the lemma's least squares) or random
    (lm/adam only); optimizer: varpro (output layer and theta_phy eliminated by least squares,
    Levenberg-Marquardt on the hidden layers), lm (Levenberg-Marquardt on all parameters, the
    earlier method) or adam; max_iter: LM iterations (Jacobian evaluations) or Adam steps;
    ftol: converged when the Gauss-Newton model predicts at most this relative cost decrease;
    restarts: draws of the hidden layers per fit, the lowest training cost kept;
    continuation_lambda: a fit without any pull toward theta_LIP (simultaneous, lambda = 0, no
    projection penalty) also starts each draw from the solution regularized with this lambda
    (homotopy; varpro only; 0: off), and keeps the lower training cost; adam_lr: Adam
    step size; validation_fraction: last part of the data held out to pick the best iterate
    (0: none); pinn_weight: weight of the PINN term (training pinn only); orthogonal_weight:
    lambda_perp of the orthogonal-projection penalty (Kon et al. 2022; dimensionless);
    weight_decay: L2 weight of the network weights (N**2 per unit weight**2); lambda_diag:
    per-parameter regularization weights (mass, viscous, coulomb, stiffness; physical units)
    overriding lambda; decimation: keep every n-th sample of the filtered training data (None:
    one sample per 8 ms whatever the record's rate, :func:`decimation_for`: 80 at 10 kHz, 8 at
    1 kHz); theta_ftol: a fit is ``converged`` only when, besides the first-order test on the
    cost, theta_phy has settled: over the last quarter of the iterations its force
    ``T . delta theta`` moved by at most this fraction of the training force's rms (else the stop
    is ``theta_moving``: a flat cost along which theta_phy still travels has no minimizer to
    converge to).
    """

    activation: Literal["tanh", "sigmoid", "softplus", "silu", "gelu", "relu"] = "tanh"
    init: Literal["optimized", "random"] = "optimized"
    optimizer: Literal["varpro", "lm", "adam"] = "varpro"
    max_iter: int = 200
    ftol: float = 1e-4
    restarts: int = 1
    continuation_lambda: float = 0.01
    adam_lr: float = 1e-3
    validation_fraction: float = 0.0
    pinn_weight: float = 1.0
    orthogonal_weight: float = 0.0
    weight_decay: float = 0.0
    lambda_diag: dict[str, float] | None = None
    decimation: int | None = None
    theta_ftol: float = 0.01

    def __post_init__(self):
        for key in ("max_iter", "decimation", "restarts"):
            value = getattr(self, key)
            if key == "decimation" and value is None:
                continue
            if not (isinstance(value, int) and value >= 1):
                raise UserError(f"pgnn.{key}: expected an integer >= 1, got {value!r}")
        if not 0.0 <= self.validation_fraction < 0.5:
            raise UserError(f"pgnn.validation_fraction: expected a number in [0, 0.5), "
                            f"got {self.validation_fraction!r}")
        if not 0.0 < self.ftol < 1.0:
            raise UserError(f"pgnn.ftol: expected a number in (0, 1), got {self.ftol!r}")
        for key in ("pinn_weight", "orthogonal_weight", "weight_decay", "continuation_lambda",
                    "theta_ftol"):
            if not getattr(self, key) >= 0:
                raise UserError(f"pgnn.{key}: expected a number >= 0, got "
                                f"{getattr(self, key)!r}")
        if not self.adam_lr > 0:
            raise UserError(f"pgnn.adam_lr: expected a number > 0, got {self.adam_lr!r}")
        if self.init == "random" and self.optimizer == "varpro":
            raise UserError("pgnn.init: 'random' needs optimizer lm or adam (varpro solves the "
                            "output layer by least squares at every step)")
        for k, v in (self.lambda_diag or {}).items():
            if k not in ("mass", "viscous", "coulomb", "stiffness") or not v >= 0:
                raise UserError(f"pgnn.lambda_diag.{k}: expected one of mass, viscous, coulomb, "
                                f"stiffness with a weight >= 0, got {v!r}")


DECIMATION_S = 0.008  # s between kept samples of the filtered data: 125 samples/s


def decimation_for(ts: float, decimation: int | None = None) -> int:
    """``decimation`` if given, else the step that keeps one sample per ``DECIMATION_S`` of a
    record sampled every ``ts`` s (80 at 10 kHz, 8 at 1 kHz): the fitting data then hold the
    same number of samples per second of record whatever its rate."""
    if decimation is not None:
        return int(decimation)
    return max(1, round(DECIMATION_S / ts))
