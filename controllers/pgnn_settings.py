"""PGNN settings: every option of a PGNN feedforward declared once.

``CONSTRAINTS`` is the one table of what each setting may be (type, range or choices) and the key
a config file gives it under; :func:`check_settings` applies it, with the rules that tie two
settings together. The config schema (``PGNNSettings`` below and ``experiments.config``'s
``FeedforwardSpec``, through ``__post_init__``) and :class:`controllers.pgnn.PGNNFeedforward`
(when built and in ``fit``) all check through it. ``PGNNSettings`` is the one declaration of the
``pgnn:`` options and their defaults: a config's ``pgnn:`` is one, and a model holds one
(``PGNNFeedforward(settings=PGNNSettings(...))``). The row keys ``hidden``, ``training`` and
``lambda`` are the model's own arguments; a config has no defaults for them (it must give them).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, fields
from typing import ClassVar

from clm_sim.errors import UserError
from clm_sim.plant import THETA_NAMES
from controllers.activations import ACTIVATION_NAMES

TRAININGS = ("simultaneous", "sequential", "pinn")
OPTIMIZERS = ("varpro", "lm", "adam")
INITS = ("optimized", "random")
# Where a fit's optimizations start (PGNNSettings.starts): its drawn hidden layers; the
# sequential solution of that draw (theta_phy held at theta_LIP, the network fitted to the LIP's
# residual: the lambda -> infinity end of the homotopy); at lambda = 0 the solution regularized
# with continuation_lambda; and the exchange of the lambda = 0 and lambda = continuation_lambda
# fits' best solutions until neither lowers its objective by more than start_rtol.
START_NAMES = ("draw", "lip", "continuation", "exchange")


@dataclass(frozen=True)
class Interval:
    """A number of ``kind`` (int or float) in ``[low, high]``; ``open`` names the excluded ends
    (``"low"``, ``"high"``, ``"both"``); ``None``: unbounded."""

    kind: type
    low: float | None = None
    high: float | None = None
    open: str = ""

    def describe(self) -> str:
        name = "an integer" if self.kind is int else "a number"
        lo_open, hi_open = self.open in ("low", "both"), self.open in ("high", "both")
        if self.high is None:
            return f"{name} {'>' if lo_open else '>='} {self.low:g}"
        return (f"{name} in {'(' if lo_open else '['}{self.low:g}, {self.high:g}"
                f"{')' if hi_open else ']'}")

    def accepts(self, value) -> bool:
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            return False
        if self.kind is int and not isinstance(value, numbers.Integral):
            return False
        if not math.isfinite(value):
            return False
        lo_open, hi_open = self.open in ("low", "both"), self.open in ("high", "both")
        if self.low is not None and (value <= self.low if lo_open else value < self.low):
            return False
        return self.high is None or (value < self.high if hi_open else value <= self.high)


@dataclass(frozen=True)
class Options:
    """One of ``choices``."""

    choices: tuple[str, ...]

    def describe(self) -> str:
        return f"one of {', '.join(self.choices)}"

    def accepts(self, value) -> bool:
        return isinstance(value, str) and value in self.choices


@dataclass(frozen=True)
class Widths:
    """Widths of the hidden layers: an integer >= 1, or a non-empty list of them."""

    def describe(self) -> str:
        return "widths >= 1 (an integer or a list of integers)"

    def accepts(self, value) -> bool:
        widths = (value,) if isinstance(value, numbers.Integral) else value
        return (isinstance(widths, (list, tuple)) and len(widths) > 0
                and all(Interval(int, 1).accepts(w) for w in widths))


@dataclass(frozen=True)
class PerParameter:
    """``None``, or a mapping from some of ``THETA_NAMES`` to numbers >= 0."""

    def describe(self) -> str:
        return f"a mapping of {', '.join(THETA_NAMES)} to weights >= 0"

    def accepts(self, value) -> bool:
        if value is None:
            return True
        return isinstance(value, dict) and all(
            k in THETA_NAMES and Interval(float, 0).accepts(v) for k, v in value.items())


@dataclass(frozen=True)
class Starts:
    """A list of distinct names of ``START_NAMES`` that holds ``draw``."""

    def describe(self) -> str:
        return f"a list of distinct names of {', '.join(START_NAMES)} holding draw"

    def accepts(self, value) -> bool:
        return (isinstance(value, (list, tuple)) and "draw" in value
                and len(set(value)) == len(value)
                and all(isinstance(v, str) and v in START_NAMES for v in value))


@dataclass(frozen=True)
class OrNone:
    """``None`` (a default that depends on the data), or what ``rule`` accepts."""

    rule: object

    def describe(self) -> str:
        return f"{self.rule.describe()} or null"

    def accepts(self, value) -> bool:
        return value is None or self.rule.accepts(value)


# The one table of lambda's spellings: a config or a results file says "lambda", Python "lam".
LAMBDA_KEYS = {"lambda": "lam", "lambda_diag": "lam_diag",
               "continuation_lambda": "continuation_lam", "lambdas": "lams",
               "paper_lambda": "paper_lam", "error_beyond_lambda_n": "error_beyond_lam_n"}
# The same spellings the other way, Python name -> file key: where code writes or reads a key.
FILE_KEYS = {python: key for key, python in LAMBDA_KEYS.items()}

# setting -> (its key in a config file, what it may be)
CONSTRAINTS = {
    "hidden": ("hidden", Widths()),
    "training": ("training", Options(TRAININGS)),
    "lam": ("lambda", Interval(float, 0)),
    "lam_diag": ("pgnn.lambda_diag", PerParameter()),
    "pinn_weight": ("pgnn.pinn_weight", Interval(float, 0)),
    "orthogonal_weight": ("pgnn.orthogonal_weight", Interval(float, 0)),
    "weight_decay": ("pgnn.weight_decay", Interval(float, 0)),
    "activation": ("pgnn.activation", Options(ACTIVATION_NAMES)),
    "init": ("pgnn.init", Options(INITS)),
    "optimizer": ("pgnn.optimizer", Options(OPTIMIZERS)),
    "max_iter": ("pgnn.max_iter", Interval(int, 1)),
    "ftol": ("pgnn.ftol", Interval(float, 0, 1, "both")),
    "restarts": ("pgnn.restarts", Interval(int, 1)),
    "continuation_lam": ("pgnn.continuation_lambda", Interval(float, 0)),
    "adam_lr": ("pgnn.adam_lr", Interval(float, 0, None, "low")),
    "validation_fraction": ("pgnn.validation_fraction", Interval(float, 0, 0.5, "high")),
    "decimation": ("pgnn.decimation", OrNone(Interval(int, 1))),
    "theta_ftol": ("pgnn.theta_ftol", Interval(float, 0)),
    "starts": ("pgnn.starts", Starts()),
    "start_rtol": ("pgnn.start_rtol", Interval(float, 0, 1, "high")),
}


MAX_WIDTH = 1024  # neurons: a hidden layer this wide is beyond what a force record identifies
MAX_LAYERS = 8  # deeper networks are beyond what a force record identifies
MAX_PARAMETERS = 20_000  # a fit's Jacobian: samples x parameters (6250 x 2e4 doubles: 1 GB)


def parameter_count(widths: tuple[int, ...]) -> int:
    """Weights and biases of a network of hidden ``widths`` on the 4 features, plus theta."""
    sizes = (4, *widths, 1)
    return sum((a + 1) * b for a, b in zip(sizes[:-1], sizes[1:])) + 4


def checked_widths(value, key: str) -> tuple[int, ...]:
    """Hidden widths read from a file: 1..``MAX_LAYERS`` layers of 1..``MAX_WIDTH`` neurons
    (integers, not booleans), checked before any network is allocated."""
    widths = [value] if isinstance(value, int) and not isinstance(value, bool) else value
    if not (isinstance(widths, (list, tuple)) and 1 <= len(widths) <= MAX_LAYERS and all(
            isinstance(w, int) and not isinstance(w, bool) and 1 <= w <= MAX_WIDTH
            for w in widths)):
        shown = repr(value) if len(repr(value)) < 60 else repr(value)[:60] + "..."
        raise UserError(f"{key}: expected 1 to {MAX_LAYERS} layers of 1 to {MAX_WIDTH} "
                        f"neurons, got {shown}")
    if parameter_count(tuple(widths)) > MAX_PARAMETERS:
        raise UserError(f"{key}: {list(widths)} has {parameter_count(tuple(widths))} "
                        f"parameters, above the limit of {MAX_PARAMETERS} of a config")
    return tuple(widths)


def check_settings(settings: dict) -> None:
    """Raise a ``UserError`` naming the config key of the first setting in ``settings`` (names
    of ``CONSTRAINTS``; missing ones are not checked) that its constraint refuses, or of a
    combination that cannot work."""
    for name, value in settings.items():
        key, rule = CONSTRAINTS[name]
        if not rule.accepts(value):
            raise UserError(f"{key}: expected {rule.describe()}, got {value!r}")
    if settings.get("init") == "random" and settings.get("optimizer", "varpro") == "varpro":
        raise UserError("pgnn.init: 'random' needs optimizer lm or adam (varpro solves the "
                        "output layer by least squares at every step)")


@dataclass(frozen=True)
class PGNNSettings:
    """The ``pgnn:`` options of a PGNN feedforward and their defaults.

    Each is declared once, here; its type and range are in one table,
    ``controllers.pgnn_settings.CONSTRAINTS``, which the config, this class and
    ``PGNNFeedforward`` all check through.

    Parameters
    ----------
    activation : str
        Of the hidden layers (``tanh`` and the others of ``CONSTRAINTS``).
    init : {"optimized", "random"}
        Optimized (the lemma's least squares) or random (lm/adam only).
    optimizer : {"varpro", "lm", "adam"}
        varpro (output layer and theta_phy eliminated by least squares, Levenberg-Marquardt
        on the hidden layers), lm (Levenberg-Marquardt on all parameters) or adam.
    max_iter : int
        LM iterations (Jacobian evaluations) or Adam steps.
    ftol : float
        Converged when the Gauss-Newton model predicts at most this relative cost decrease.
    restarts : int
        Draws of the hidden layers per fit, the lowest training cost kept.
    continuation_lam : float
        A fit without any pull toward theta_LIP (simultaneous, lambda = 0, no projection
        penalty) also starts each draw from the solution regularized with this lambda
        (homotopy; varpro only; 0: off), and keeps the lower training cost.
    adam_lr : float
        Adam step size.
    validation_fraction : float
        Last part of the data held out to pick the best iterate (0: none).
    pinn_weight : float
        Weight of the PINN term (training pinn only).
    orthogonal_weight : float
        lambda_perp of the orthogonal-projection penalty (Kon et al. 2022; dimensionless).
    weight_decay : float
        L2 weight of the network weights (N**2 per unit weight**2).
    lam_diag : dict, optional
        Per-parameter regularization weights (mass, viscous, coulomb, stiffness; physical
        units) overriding lambda.
    decimation : int, optional
        Keep every n-th sample of the filtered training data (None: one sample per 8 ms
        whatever the record's rate: 80 at 10 kHz, 8 at 1 kHz).
    theta_ftol : float
        A fit is ``converged`` only when, besides the first-order test on the cost, theta_phy
        has settled: over the last quarter of the iterations its force ``T . delta theta``
        moved by less than this fraction of the training force's rms, by the margin of
        :func:`controllers.pgnn.fit_record.verdict` (beyond the margin the stop is
        ``theta_moving``: a flat cost along which theta_phy still travels has no minimizer to
        converge to; within it, ``at_edge``).
    starts : tuple of str
        Where each draw's optimizations start (``START_NAMES``): ``draw``; ``lip``, from the
        draw's sequential solution; ``continuation``, at lambda = 0 from the draw's solution
        regularized with continuation_lam; ``exchange``, the lambda = 0 and lambda =
        continuation_lam fits of the draw start from each other's best until neither improves
        by more than start_rtol (implies the continuation). The lowest objective is kept.
    start_rtol : float
        Two starts agree when their objectives differ by at most this fraction of the lower
        (the fit record counts the starts that agree with the kept one).

    Raises
    ------
    UserError
        A setting its constraint refuses (named by its config key), or ``init: random`` with
        the varpro optimizer.

    Examples
    --------
    >>> from clm_sim import PGNNSettings
    >>> fast = PGNNSettings(max_iter=50, weight_decay=1e-5)
    >>> fast.max_iter, fast.optimizer
    (50, 'varpro')
    >>> PGNNSettings(ftol=1.0)
    Traceback (most recent call last):
    ...
    clm_sim.errors.UserError: pgnn.ftol: expected a number in (0, 1), got 1.0
    """

    activation: str = "tanh"
    init: str = "optimized"
    optimizer: str = "varpro"
    max_iter: int = 200
    ftol: float = 1e-4
    restarts: int = 1
    continuation_lam: float = 0.01
    adam_lr: float = 1e-3
    validation_fraction: float = 0.0
    pinn_weight: float = 1.0
    orthogonal_weight: float = 0.0
    weight_decay: float = 0.0
    lam_diag: dict[str, float] | None = None
    decimation: int | None = None
    theta_ftol: float = 0.01
    starts: tuple[str, ...] = ("draw", "continuation")
    start_rtol: float = 1e-3

    aliases: ClassVar[dict[str, str]] = {k: LAMBDA_KEYS[k] for k in ("lambda_diag",
                                                                      "continuation_lambda")}

    def __post_init__(self):
        check_settings({f.name: getattr(self, f.name) for f in fields(self)})
        object.__setattr__(self, "starts", tuple(self.starts))  # a file's list, one form


DECIMATION_S = 0.008  # s between kept samples of the filtered data: 125 samples/s


def decimation_for(ts: float, decimation: int | None = None) -> int:
    """``decimation`` if given, else the step that keeps one sample per ``DECIMATION_S`` of a
    record sampled every ``ts`` s (80 at 10 kHz, 8 at 1 kHz): the fitting data then hold the
    same number of samples per second of record whatever its rate."""
    if decimation is not None:
        return int(decimation)
    return max(1, round(DECIMATION_S / ts))
