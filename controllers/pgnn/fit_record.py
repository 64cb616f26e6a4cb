"""How a PGNN fit went: a frozen record, kept by the model as ``fit_``.

:class:`FitRecord` is what :meth:`controllers.pgnn.PGNNFeedforward.fit` learned about its own
optimization (why it stopped, iterations, the cost split into the data and the regularizers, the
first-order measure, how theta_phy moved, every start it tried). The model file stores it under
``"fit"`` through :meth:`FitRecord.to_json` (the keys are the file format's; the Python names say
``lam``), and :meth:`FitRecord.from_json` reads it back. Every consumer (the testbed's table
rows, the measured-record rows, the failure map, the studies) reads its fields: none restates
its keys.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from clm_sim.errors import UserError
from clm_sim.plant import THETA_NAMES
from controllers.pgnn_settings import LAMBDA_KEYS

LAMBDA_FILE_KEYS = {python: key for key, python in LAMBDA_KEYS.items()}

if TYPE_CHECKING:  # the cost module imports torch; a record is read without it
    from controllers.pgnn.cost import CostTerms


@dataclass(frozen=True)
class Iterate:
    """One accepted iteration of a fit, as ``PGNNFeedforward.history_`` keeps it: the iteration,
    the optimizer's cost and its terms (N**2; the names of
    :data:`controllers.pgnn.cost.TERMS`), theta_phy (named, SI units) and, with a held-out
    check, the held-out mean squared force error (N**2). The model file stores the history
    through :meth:`to_json` (its keys are the file format's)."""

    iteration: int
    cost: float
    data: float
    deviation: float
    pinn: float
    orthogonal: float
    weight_decay: float
    theta: dict[str, float]
    validation: float | None = None

    @classmethod
    def at(cls, iteration: int, cost: float, terms: CostTerms, theta: dict[str, float],
           validation: float | None = None) -> Iterate:
        """The iterate of cost ``cost`` made of ``terms`` (N**2)."""
        return cls(iteration, cost, data=terms.data, deviation=terms.deviation, pinn=terms.pinn,
                   orthogonal=terms.orthogonal, weight_decay=terms.weight_decay, theta=theta,
                   validation=validation)

    def to_json(self) -> dict:
        out = {"iteration": self.iteration, "cost": self.cost, "data": self.data,
               "deviation": self.deviation, "pinn": self.pinn, "orthogonal": self.orthogonal,
               "weight_decay": self.weight_decay, "theta": dict(self.theta)}
        if self.validation is not None:
            out["validation"] = self.validation
        return out

    @classmethod
    def from_json(cls, d) -> Iterate:
        """An entry of a model file's ``history`` (a term missing from an older file: 0)."""
        if not isinstance(d, dict) or not isinstance(d.get("theta"), dict):
            raise UserError("history: expected entries with 'iteration', 'cost' and 'theta'")
        try:
            return cls(int(d["iteration"]), float(d["cost"]),
                       *(float(d.get(t, 0.0)) for t in ("data", "deviation", "pinn",
                                                         "orthogonal", "weight_decay")),
                       theta={k: float(d["theta"][k]) for k in THETA_NAMES},
                       validation=(None if d.get("validation") is None
                                   else float(d["validation"])))
        except (KeyError, TypeError, ValueError) as exc:
            raise UserError(f"history: an entry lacks or mistypes {exc}") from None


@dataclass(frozen=True)
class ThetaPoint:
    """theta_phy (named, SI units) and the data cost (N**2) at one iteration of a fit."""

    iteration: int
    data_cost: float
    theta: dict[str, float]

    def to_json(self) -> dict:
        return {"iteration": self.iteration, "data_cost": self.data_cost, **self.theta}

    @classmethod
    def from_json(cls, d: dict) -> ThetaPoint:
        return cls(int(d["iteration"]), float(d["data_cost"]),
                   {k: float(d[k]) for k in THETA_NAMES})


@dataclass(frozen=True)
class Start:
    """One optimization of a fit: ``start`` (``draw``: from the random hidden layers; ``lip``:
    from the draw's sequential solution; ``continuation``: from the solution regularized with
    ``continuation_lam``; ``exchange``: at lambda = continuation_lam, from the lambda = 0 fit's
    best), its final training cost (the objective: data cost and every regularizer, N**2), why
    it stopped, its iterations and whether another fit had run it already (``reused``: taken
    from the start cache, no iteration spent)."""

    start: str
    cost: float
    stop: str
    iterations: int
    reused: bool = field(default=False, compare=False)  # bookkeeping, not the outcome

    def to_json(self) -> dict:
        return {"start": self.start, "cost": self.cost, "stop": self.stop,
                "iterations": self.iterations, "reused": self.reused}

    @classmethod
    def from_json(cls, d: dict) -> Start:
        return cls(str(d["start"]), float(d["cost"]), str(d["stop"]), int(d["iterations"]),
                   bool(d.get("reused", False)))


VERDICT_MARGIN = 3.0
"""The factor by which a convergence test's measure must clear its threshold for the verdict to
stand (:func:`verdict`). A change of rounding (another BLAS, another factorization of the same
linear algebra) moves the end of a fit in a flat valley: between two such roundings of the paper
table's fits, theta_phy's travel over the last quarter of a fit changed by up to 2.3 times (the
converging rows' 100 fits), so a verdict decided within a factor of 3 of its threshold is one
that the last bits decide."""


def verdict(cost_stop: str, first_order: float | None, ftol: float,
            theta_moved: float | None = None, theta_ftol: float | None = None,
            margin: float = VERDICT_MARGIN) -> str:
    """A fit's stop judged with a margin: ``converged`` where the optimizer's first-order test
    held (``cost_stop`` ``converged``: the Gauss-Newton model predicts at most ``ftol``
    relative decrease) and theta_phy's force moved by at most ``theta_ftol / margin`` over the
    last quarter of the iterations; ``theta_moving`` where it moved more than
    ``theta_ftol * margin`` (the cost test held, or was at its edge); ``at_edge`` where neither
    test fails by more than its margin and one is within it (theta's travel within a factor
    ``margin`` of ``theta_ftol``, or a fit at its iteration cap whose first-order measure is
    within a factor ``margin`` of ``ftol``): another rounding may put it on either side;
    otherwise the optimizer's stop (``max_iter``, ``stalled``). ``theta_moved`` None: no theta
    test (a sequential fit)."""
    if cost_stop == "converged":
        cost = "held"
    elif cost_stop == "max_iter" and first_order is not None and first_order <= margin * ftol:
        cost = "edge"
    else:
        return cost_stop
    theta = "held"
    if theta_moved is not None and theta_ftol is not None:
        if theta_moved > theta_ftol * margin:
            return "theta_moving"
        if theta_moved > theta_ftol / margin:
            theta = "edge"
    return "converged" if cost == theta == "held" else "at_edge"


@dataclass(frozen=True)
class FitRecord:
    """How one PGNN fit stopped and what it cost.

    stop: ``converged``, ``at_edge``, ``theta_moving`` (the cost test held while theta_phy still
    travelled), ``max_iter`` or ``stalled`` (:func:`verdict`; a pinned fit given an absolute
    tolerance also ``resolved``); cost_stop: the optimizer's own verdict before the theta test;
    iterations: of the kept start; data_cost, reg_cost: the training cost's data term and the sum
    of its other terms (N**2); grad_norm, first_order: the optimizer's last gradient norm and
    first-order measure (:func:`controllers.optim.first_order_measure`); ftol, max_iter: the
    settings they were tested against. A free fit (``fit``) also has: iterations_total (over
    every start listed, whoever ran it), iterations_run and iterations_reused (of every
    optimization the fit ran, listed or not, and of those it took from other fits' start cache:
    over a table, the first sums to the iterations its command ran), theta_moved (how far
    theta_phy's force still moved over the last quarter of the iterations, a fraction of the
    training force's rms) and theta_ftol, theta_path (theta_phy
    at checkpoint iterations), continuation_lam (the lambda of the continuation start where one
    ran, else 0), start (the kind of start kept), starts and start_rtol (two starts agree when
    their objectives differ by at most this fraction of the lower). A pinned fit
    (``fit_pinned``) has pinned (name -> value held fixed, SI units) instead.
    """

    stop: str
    cost_stop: str
    iterations: int
    data_cost: float
    reg_cost: float
    grad_norm: float | None
    first_order: float | None
    ftol: float
    max_iter: int
    iterations_total: int | None = None
    # bookkeeping, not the outcome (a fit that took a start from the cache equals one that ran it)
    iterations_run: int | None = field(default=None, compare=False)
    iterations_reused: int | None = field(default=None, compare=False)
    theta_moved: float | None = None
    theta_ftol: float | None = None
    theta_path: tuple[ThetaPoint, ...] = ()
    continuation_lam: float | None = None
    start: str | None = None
    starts: tuple[Start, ...] = ()
    pinned: dict[str, float] | None = None
    start_rtol: float | None = None

    @property
    def objective(self) -> float:
        """The kept fit's training cost: data cost plus every regularizer (N**2)."""
        return self.data_cost + self.reg_cost

    @property
    def agree(self) -> int:
        """How many starts end within ``start_rtol`` of the lowest objective (the kept one's
        among them; 1 for a fit of one start)."""
        if len(self.starts) < 2 or self.start_rtol is None:
            return 1
        low = min(s.cost for s in self.starts)
        return sum(s.cost <= low * (1 + self.start_rtol) for s in self.starts)

    @property
    def spread(self) -> float:
        """The highest start's objective above the lowest, a fraction of the lowest (0 for one
        start)."""
        if len(self.starts) < 2:
            return 0.0
        costs = [s.cost for s in self.starts]
        return (max(costs) - min(costs)) / min(costs)

    @property
    def multiple_optima(self) -> bool:
        """Whether two starts that both passed the optimizer's test end more than
        ``start_rtol`` apart: distinct local minima of the objective."""
        if self.start_rtol is None:
            return False
        done = sorted(s.cost for s in self.starts if s.stop == "converged")
        return len(done) > 1 and done[-1] > done[0] * (1 + self.start_rtol)

    @property
    def converged(self) -> bool:
        return self.stop == "converged"

    @property
    def at_edge(self) -> bool:
        """Whether a convergence test was within its margin (:func:`verdict`)."""
        return self.stop == "at_edge"

    @property
    def restarts(self) -> int:
        """How many optimizations the fit ran (1 for a pinned fit)."""
        return len(self.starts) or 1

    def __str__(self) -> str:
        return f"{self.stop} after {self.iterations} iterations, data cost {self.data_cost:.5g} N²"

    def to_json(self) -> dict:
        """The model file's ``"fit"`` section (its keys are the file format)."""
        if self.pinned is not None:
            return {"stop": self.stop, "cost_stop": self.cost_stop,
                    "iterations": self.iterations, "data_cost": self.data_cost,
                    "pinned": dict(self.pinned), "reg_cost": self.reg_cost,
                    "first_order": self.first_order, "grad_norm": self.grad_norm,
                    "ftol": self.ftol, "max_iter": self.max_iter}
        return {"stop": self.stop, "cost_stop": self.cost_stop, "iterations": self.iterations,
                "iterations_total": self.iterations_total,
                "iterations_run": self.iterations_run,
                "iterations_reused": self.iterations_reused, "theta_moved": self.theta_moved,
                "theta_ftol": self.theta_ftol,
                "theta_path": [p.to_json() for p in self.theta_path],
                LAMBDA_FILE_KEYS["continuation_lam"]: self.continuation_lam,
                "data_cost": self.data_cost,
                "reg_cost": self.reg_cost, "grad_norm": self.grad_norm,
                "first_order": self.first_order, "ftol": self.ftol, "max_iter": self.max_iter,
                "start": self.start, "starts": [s.to_json() for s in self.starts],
                "start_rtol": self.start_rtol}

    @classmethod
    def from_json(cls, d, where: str = "fit") -> FitRecord | None:
        """The record of a model file's ``"fit"`` section (None: the file has none);
        ``UserError`` naming ``where`` when it is not one."""
        if d is None:
            return None
        try:
            pinned = d.get("pinned")
            return cls(
                stop=str(d["stop"]), cost_stop=str(d.get("cost_stop", d["stop"])),
                iterations=int(d["iterations"]), data_cost=float(d["data_cost"]),
                reg_cost=float(d["reg_cost"]), grad_norm=_number(d.get("grad_norm")),
                first_order=_number(d.get("first_order")), ftol=float(d["ftol"]),
                max_iter=int(d["max_iter"]),
                iterations_total=_integer(d.get("iterations_total")),
                iterations_run=_integer(d.get("iterations_run")),
                iterations_reused=_integer(d.get("iterations_reused")),
                theta_moved=_number(d.get("theta_moved")),
                theta_ftol=_number(d.get("theta_ftol")),
                theta_path=tuple(ThetaPoint.from_json(p) for p in d.get("theta_path") or ()),
                continuation_lam=_number(d.get(LAMBDA_FILE_KEYS["continuation_lam"])),
                start=d.get("start"),
                starts=tuple(Start.from_json(s) for s in d.get("starts") or ()),
                start_rtol=_number(d.get("start_rtol")),
                pinned=None if pinned is None else {str(k): float(v) for k, v in
                                                    pinned.items()})
        except (AttributeError, KeyError, TypeError, ValueError) as exc:
            raise UserError(f"{where}: not a fit record ({type(exc).__name__}: {exc})") from None


def _number(x) -> float | None:
    return None if x is None else float(x)


def _integer(x) -> int | None:
    return None if x is None else int(x)


def fit_fields(d) -> dict:
    """The fields of a :class:`FitRecord` that a table row's ``fits`` entry
    (:class:`experiments.table.FitSummary`) carries too, read from either (the keys are the
    files'): how the fit stopped, its iterations and costs (N**2), theta_phy's path, the
    continuation lambda and the starts."""
    return dict(stop=str(d["stop"]), cost_stop=str(d.get("cost_stop", d["stop"])),
                iterations=int(d["iterations"]),
                iterations_total=_integer(d.get("iterations_total")),
                iterations_run=_integer(d.get("iterations_run")),
                iterations_reused=_integer(d.get("iterations_reused")),
                data_cost=float(d["data_cost"]), reg_cost=float(d["reg_cost"]),
                grad_norm=_number(d.get("grad_norm")), first_order=_number(d.get("first_order")),
                theta_moved=_number(d.get("theta_moved")),
                theta_path=tuple(ThetaPoint.from_json(p) for p in d.get("theta_path") or ()),
                continuation_lam=_number(d.get(LAMBDA_FILE_KEYS["continuation_lam"])),
                start=d.get("start"),
                starts=tuple(Start.from_json(s) for s in d.get("starts") or ()),
                start_rtol=_number(d.get("start_rtol")))
