"""The profiles study's record as typed values, and the one mapping to and from
``identifiability.json``'s ``"sizes"``.

:mod:`experiments.studies.profiles.identifiability` builds the pieces (:class:`Point`,
:class:`ValleyRange`, :class:`ParameterProfile`, :class:`SloppyDirections`, :class:`LipIntervals`),
:func:`experiments.studies.profiles.study.summarize` assembles a :class:`SizeRecord` per network
size; the report and :func:`experiments.studies.profiles.figures.identifiability_figure` read their
fields. The file's keys are written and read only here, in each type's ``to_json``/``from_json``
(``tests/test_profiles.py`` scans the other modules for them).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clm_sim.plant import THETA_NAMES
from controllers.pgnn_settings import FILE_KEYS

SIDES = ("down", "up")  # the two directions of a profile, in the file's words


def _names(d: dict) -> dict[str, float]:
    return {k: float(d[k]) for k in THETA_NAMES}


@dataclass(frozen=True)
class Point:
    """One profile point: the value held (SI), its data cost (N**2), the optimizer's stop reason
    and iterations, how much its data cost fell over its last iterations (N**2, ``tail``; how
    far from converged a ``max_iter`` point still is), the fit's hidden layers (the next
    point's start; not in the file), its last first-order measure
    (:func:`controllers.optim.first_order_measure`: the relative decrease the Gauss-Newton
    model predicts; None: not measured) and the two convergence tests it was held to: ``ftol``
    (relative: ``first_order <= ftol``) and ``atol`` (the profile's resolution, N**2: the
    predicted absolute decrease ``data_cost * first_order <= atol`` and the fall over the last
    iterations ``tail <= atol``; None: not tested). A point that rose above the profile's level
    was continued before the rise counted: ``continued`` of its iterations are that
    continuation's, and ``confirmed_from`` is its data cost before it (N**2; None: not
    continued)."""

    value: float
    data_cost: float
    stop: str
    iterations: int
    beta: np.ndarray | None = None
    tail: float = 0.0
    first_order: float | None = None
    ftol: float | None = None
    atol: float | None = None
    continued: int = 0
    confirmed_from: float | None = None

    @property
    def predicted_decrease(self) -> float | None:
        """The absolute decrease of the data cost (N**2) the Gauss-Newton model predicts."""
        return None if self.first_order is None else self.data_cost * self.first_order

    @property
    def relative_test(self) -> bool:
        """The optimizer's own convergence test: predicted relative decrease <= ftol."""
        return (self.first_order is not None and self.ftol is not None
                and self.first_order <= self.ftol)

    @property
    def resolution_test(self) -> bool:
        """The profile's test: the predicted absolute decrease and the fall over the last
        iterations both <= atol (a fraction of delta)."""
        return (self.first_order is not None and self.atol is not None
                and self.predicted_decrease <= self.atol and self.tail <= self.atol)

    @property
    def settled(self) -> bool:
        """Whether either test holds (else the point is an upper bound on the profile)."""
        return self.relative_test or self.resolution_test

    def to_json(self) -> dict:
        return {"value": self.value, "data_cost": self.data_cost, "stop": self.stop,
                "iterations": self.iterations, "tail_decrease": self.tail,
                "first_order": self.first_order, "predicted_decrease": self.predicted_decrease,
                "relative_test": self.relative_test, "resolution_test": self.resolution_test,
                "continued_iterations": self.continued, "confirmed_from": self.confirmed_from}

    @classmethod
    def from_json(cls, d: dict, *, ftol: float | None, atol: float | None) -> Point:
        """A point of the file, held to the record's ``ftol`` and ``atol`` (the file stores
        the tests' outcomes too; :meth:`to_json` of the result gives them back)."""
        return cls(value=d["value"], data_cost=d["data_cost"], stop=d["stop"],
                   iterations=d["iterations"], tail=d.get("tail_decrease", 0.0),
                   first_order=d.get("first_order"), ftol=ftol, atol=atol,
                   continued=d.get("continued_iterations", 0),
                   confirmed_from=d.get("confirmed_from"))


@dataclass(frozen=True)
class Walk:
    """One direction of a profile's continuation: its points in the order fitted and why it
    ended (:data:`experiments.studies.profiles.identifiability.ENDS`)."""

    points: tuple[Point, ...]
    end: str


@dataclass(frozen=True)
class ValleyRange:
    """The block of a profile within delta of the best data cost around its start: ``limits``
    (low, high; SI units; None: the profile never comes within delta), whether each side is
    open (the block reaches the last point on that side; the limit is then that point) and the
    first and last values inside (None with no block)."""

    limits: tuple[float, float] | None
    open: tuple[bool, bool]
    inside: tuple[float, float] | None = None

    def contains(self, value: float) -> bool:
        """Whether ``value`` lies in the range (an open side extends to infinity)."""
        if self.limits is None:
            return False
        lo, hi = self.limits
        return (self.open[0] or value >= lo) and (self.open[1] or value <= hi)

    def to_json(self) -> dict:
        out = {"range": None if self.limits is None else list(self.limits),
               "open": list(self.open)}
        if self.inside is not None:
            out["inside"] = list(self.inside)
        return out

    @classmethod
    def from_json(cls, d: dict) -> ValleyRange:
        return cls(None if d["range"] is None else tuple(d["range"]), tuple(d["open"]),
                   None if d.get("inside") is None else tuple(d["inside"]))


@dataclass(frozen=True)
class Sides:
    """One quantity for the two directions of a profile (toward lower and higher values)."""

    down: object
    up: object

    def to_json(self) -> dict:
        return dict(zip(SIDES, (self.down, self.up)))

    @classmethod
    def from_json(cls, d: dict) -> Sides:
        return cls(*(d[s] for s in SIDES))


@dataclass(frozen=True)
class ParameterProfile:
    """One parameter's profile: the value it started from (theta* of the best fit, SI), its
    points (lowest value first, the start among them), the search bounds (low, high), the range
    within delta, each direction's end (``rises``, ``rises (not converged)``: at a point that
    passed neither test, or ``bound``), whether its costs rise monotonically away from the
    start, and why each open side is open (None: closed)."""

    start: float
    points: tuple[Point, ...]
    bound: tuple[float, float]
    valley: ValleyRange
    ends: Sides
    monotone: Sides
    why_open: tuple[str | None, str | None]

    def to_json(self) -> dict:
        return {**self.valley.to_json(), "profile": [p.to_json() for p in self.points],
                "start": self.start, "bound": list(self.bound), "ends": self.ends.to_json(),
                "monotone": self.monotone.to_json(), "why_open": list(self.why_open)}

    @classmethod
    def from_json(cls, d: dict, *, ftol: float | None, atol: float | None
                  ) -> ParameterProfile:
        return cls(d["start"], tuple(Point.from_json(p, ftol=ftol, atol=atol)
                                     for p in d["profile"]),
                   tuple(d["bound"]), ValleyRange.from_json(d), Sides.from_json(d["ends"]),
                   Sides.from_json(d["monotone"]), tuple(d["why_open"]))


@dataclass(frozen=True)
class SmallDirection:
    """One small eigenpair of a fit's scaled Gauss-Newton matrix: the eigenvalue (N**2 per
    unit step), its ratio to the largest, the theta part of the unit vector (named) and the
    network's share of the vector."""

    eigenvalue: float
    relative: float
    theta: dict[str, float]
    network_share: float

    def to_json(self) -> dict:
        return {"eigenvalue": self.eigenvalue, "relative": self.relative,
                "theta": dict(self.theta), "network_share": self.network_share}

    @classmethod
    def from_json(cls, d: dict) -> SmallDirection:
        return cls(d["eigenvalue"], d["relative"], _names(d["theta"]), d["network_share"])


@dataclass(frozen=True)
class ThetaDirection:
    """An eigenpair of the Schur complement of the network block: what is left of a theta
    direction (unit vector, named) once the network has absorbed what it can (N**2 per unit)."""

    eigenvalue: float
    direction: dict[str, float]

    def to_json(self) -> dict:
        return {"eigenvalue": self.eigenvalue, "direction": dict(self.direction)}

    @classmethod
    def from_json(cls, d: dict) -> ThetaDirection:
        return cls(d["eigenvalue"], _names(d["direction"]))


@dataclass(frozen=True)
class SloppyDirections:
    """The sloppy directions of one fit
    (:func:`experiments.studies.profiles.identifiability.sloppy_directions`): the largest eigenvalue
    (N**2), the smallest eigenpairs and the theta directions (smallest eigenvalue first)."""

    largest: float
    smallest: tuple[SmallDirection, ...]
    theta: tuple[ThetaDirection, ...]

    def to_json(self) -> dict:
        return {"largest": self.largest, "smallest": [s.to_json() for s in self.smallest],
                "theta": [t.to_json() for t in self.theta]}

    @classmethod
    def from_json(cls, d: dict) -> SloppyDirections:
        return cls(d["largest"], tuple(map(SmallDirection.from_json, d["smallest"])),
                   tuple(map(ThetaDirection.from_json, d["theta"])))


@dataclass(frozen=True)
class LipIntervals:
    """The LIP on the fitting samples (named theta, SI units) with white-noise and Newey-West
    standard errors, the residual's lag-1 autocorrelation, the lags used, the samples and the
    residual's autocorrelation at the lags used."""

    theta: dict[str, float]
    std_white: dict[str, float]
    std_newey_west: dict[str, float]
    lag1_autocorr: float
    lags: int
    n_samples: int
    autocorr_at_lags: float | None = None

    def to_json(self) -> dict:
        return {"theta": dict(self.theta), "std_white": dict(self.std_white),
                "std_newey_west": dict(self.std_newey_west),
                "lag1_autocorr": self.lag1_autocorr, "lags": self.lags,
                "n_samples": self.n_samples, "autocorr_at_lags": self.autocorr_at_lags}

    @classmethod
    def from_json(cls, d: dict) -> LipIntervals:
        return cls(_names(d["theta"]), _names(d["std_white"]), _names(d["std_newey_west"]),
                   d["lag1_autocorr"], d["lags"], d["n_samples"], d.get("autocorr_at_lags"))


@dataclass(frozen=True)
class FirstStop:
    """Where a record's fit stood before its polish: data cost (N**2), stop, iterations."""

    data_cost: float
    stop: str
    iterations: int

    def to_json(self) -> dict:
        return {"data_cost": self.data_cost, "stop": self.stop, "iterations": self.iterations}

    @classmethod
    def from_json(cls, d: dict) -> FirstStop:
        return cls(d["data_cost"], d["stop"], d["iterations"])


@dataclass(frozen=True)
class RecordFit:
    """One PGNN fit on a training record (lambda = 0): the record's seed, the network draw,
    the data cost (N**2), stop and iterations after the polish, where it stood before
    (``first``), its last ``tail`` decrease (N**2), theta (named, SI) and its sloppy
    directions."""

    seed: int
    draw: int
    data_cost: float
    stop: str
    iterations: int
    first: FirstStop
    tail_decrease: float
    theta: dict[str, float]
    sloppy: SloppyDirections | None = None

    def to_json(self, with_sloppy: bool = True) -> dict:
        out = {"seed": self.seed, "draw": self.draw, "data_cost": self.data_cost,
               "stop": self.stop, "iterations": self.iterations, "first": self.first.to_json(),
               "tail_decrease": self.tail_decrease, "theta": dict(self.theta)}
        if with_sloppy:
            out["sloppy"] = self.sloppy.to_json()
        return out

    @classmethod
    def from_json(cls, d: dict, seed: int | None = None) -> RecordFit:
        return cls(d.get("seed", seed), d["draw"], d["data_cost"], d["stop"], d["iterations"],
                   FirstStop.from_json(d["first"]), d["tail_decrease"], _names(d["theta"]),
                   SloppyDirections.from_json(d["sloppy"]) if "sloppy" in d else None)


@dataclass(frozen=True)
class MarkedFit:
    """A fit drawn on the profiles: its λ, data cost (N²) and θ_phy."""

    lam: float
    data_cost: float
    theta: dict[str, float]

    def to_json(self) -> dict:
        return {FILE_KEYS["lam"]: self.lam, "data_cost": self.data_cost, "theta": dict(self.theta)}

    @classmethod
    def from_json(cls, d: dict) -> MarkedFit:
        return cls(d[FILE_KEYS["lam"]], d["data_cost"], _names(d["theta"]))


@dataclass(frozen=True)
class Check:
    """A resolved point continued without the resolution stop: its parameter and value (SI),
    its data cost and predicted decrease when resolved (N**2), the data cost after the
    continuation, and the continuation's stop and iterations."""

    name: str
    value: float
    data_cost: float
    predicted_decrease: float
    continued_cost: float
    stop: str
    iterations: int

    @property
    def moved(self) -> float:
        """How far the data cost still fell (N**2)."""
        return self.data_cost - self.continued_cost

    def to_json(self) -> dict:
        return {"name": self.name, "value": self.value, "data_cost": self.data_cost,
                "predicted_decrease": self.predicted_decrease,
                "continued_cost": self.continued_cost, "stop": self.stop,
                "iterations": self.iterations, "moved": self.moved}

    @classmethod
    def from_json(cls, d: dict) -> Check:
        return cls(d["name"], d["value"], d["data_cost"], d["predicted_decrease"],
                   d["continued_cost"], d["stop"], d["iterations"])


@dataclass(frozen=True)
class WalkSettings:
    """How the profiles were walked: iterations per point at most, points per direction,
    first step and span (units of each parameter's scale), bisections, the records' polish
    iterations, the resolution (a fraction of delta) and its absolute value (N**2), the
    optimizer's relative tolerance and the check's iterations."""

    max_iter: int
    points: int
    step: float
    span: float
    refine: int
    polish: int
    resolution: float
    atol: float
    ftol: float
    check_iter: int

    _KEYS = ("max_iter", "points", "step", "span", "refine", "polish", "resolution", "atol",
             "ftol", "check_iter")

    def to_json(self) -> dict:
        return {k: getattr(self, k) for k in self._KEYS}

    @classmethod
    def from_json(cls, d: dict) -> WalkSettings:
        return cls(*(d[k] for k in cls._KEYS))


DELTA_FROM = "spread over records"  # what the threshold is (the file states it)


@dataclass(frozen=True)
class SizeRecord:
    """The identifiability record of one network size: the best data cost seen (N²), the
    threshold delta (N², the spread of the best data cost over the records) with the per-record
    costs and seeds, the profiles' start (the best fit on the first record), each parameter's
    scale (SI per rms force), the walk's settings, the fits to mark on the figure, every
    record's fit, the LIP's intervals on the first record, its data cost per record and its
    mean and standard deviation over the records (named), each parameter's profile and the
    checks of the resolution test."""

    best_data_cost: float
    delta: float
    best_cost_per_record: tuple[float, ...]
    seeds: tuple[int, ...]
    start: RecordFit
    scale: dict[str, float]
    settings: WalkSettings
    fits: tuple[MarkedFit, ...]
    record_fits: tuple[RecordFit, ...]
    lip_intervals: LipIntervals
    lip_cost_per_record: tuple[float, ...]
    lip_mean: dict[str, float]
    lip_std: dict[str, float]
    parameters: dict[str, ParameterProfile]
    checks: tuple[Check, ...] = ()

    @property
    def points(self) -> list[Point]:
        """Every parameter's points (the start once per parameter)."""
        return [p for e in self.parameters.values() for p in e.points]

    def to_json(self) -> dict:
        start = self.start.to_json(with_sloppy=False)
        del start["seed"]
        return {
            "best_data_cost": self.best_data_cost, "delta": self.delta,
            "delta_from": DELTA_FROM, "best_cost_per_record": list(self.best_cost_per_record),
            "seeds": list(self.seeds), "start": start, "scale": dict(self.scale),
            **self.settings.to_json(),
            "checks": [c.to_json() for c in self.checks],
            "fits": [f.to_json() for f in self.fits],
            "record_fits": [f.to_json() for f in self.record_fits],
            "lip_intervals": self.lip_intervals.to_json(),
            "lip_cost_per_record": list(self.lip_cost_per_record),
            "lip_over_records": {"mean": dict(self.lip_mean), "std": dict(self.lip_std)},
            "parameters": {k: e.to_json() for k, e in self.parameters.items()}}

    @classmethod
    def from_json(cls, d: dict) -> SizeRecord:
        settings = WalkSettings.from_json(d)
        return cls(
            d["best_data_cost"], d["delta"], tuple(d["best_cost_per_record"]),
            tuple(d["seeds"]), RecordFit.from_json(d["start"], seed=d["seeds"][0]),
            _names(d["scale"]), settings, tuple(map(MarkedFit.from_json, d["fits"])),
            tuple(map(RecordFit.from_json, d["record_fits"])),
            LipIntervals.from_json(d["lip_intervals"]), tuple(d["lip_cost_per_record"]),
            _names(d["lip_over_records"]["mean"]), _names(d["lip_over_records"]["std"]),
            {k: ParameterProfile.from_json(d["parameters"][k], ftol=settings.ftol,
                                           atol=settings.atol) for k in THETA_NAMES},
            tuple(map(Check.from_json, d["checks"])))


def sizes_to_json(sizes: dict[int, SizeRecord]) -> dict:
    """``identifiability.json``'s ``"sizes"``: per network size (a string key) its record."""
    return {str(k): rec.to_json() for k, rec in sizes.items()}


def study_to_json(sizes: dict[int, SizeRecord], wall_time_s: float) -> dict:
    """The whole ``identifiability.json``: the study's wall time (s) and its records."""
    return {"wall_time_s": wall_time_s, "sizes": sizes_to_json(sizes)}


def sizes_from_json(sizes: dict) -> dict[int, SizeRecord]:
    """``{n_l: SizeRecord}`` of the study's ``"sizes"`` (order kept)."""
    return {int(key): SizeRecord.from_json(rec) for key, rec in sizes.items()}


@dataclass(frozen=True)
class ProfilesResult:
    """The study's result: the record per network size and the study's wall time (s)."""

    sizes: dict[int, SizeRecord]
    wall_time_s: float

    def to_json(self) -> dict:
        return study_to_json(self.sizes, self.wall_time_s)

    @classmethod
    def from_json(cls, d: dict) -> ProfilesResult:
        return cls(sizes_from_json(d["sizes"]), d["wall_time_s"])
