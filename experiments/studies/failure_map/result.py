"""The failure map's result as typed values, and the one mapping to and from ``failure_map.json``.

:func:`experiments.studies.failure_map.study.summarize` builds a :class:`FailureMapResult`; the
report and the figures (:mod:`experiments.studies.failure_map.figures`) read its fields. The file's
names for the two fits of a cell ("lam0": lambda = 0, "reg": the regularized fit) live only in
:data:`_JSON_KEYS`, used by ``to_json``/``from_json`` here.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Generic, TypeVar

import numpy as np

from clm_sim.schema import build, to_plain
from controllers.pgnn_settings import FILE_KEYS, LAMBDA_KEYS
from experiments.stats.paired import LogRatio
from experiments.studies.failure_map.settings import FailureMapSettings

T = TypeVar("T")

VERDICTS = ("holds", "reversed", "undecided")

# failure_map.json names the two fits of a cell by these keys (the file's format).
_JSON_KEYS = {"unregularized": "lam0", "regularized": "reg"}


@dataclass(frozen=True)
class BothFits(Generic[T]):
    """One quantity for the two fits of a cell: without regularization (lambda = 0) and with
    the study's lambda."""

    unregularized: T
    regularized: T

    def to_json(self, value=lambda v: v) -> dict:
        """``{"lam0": value(unregularized), "reg": value(regularized)}``."""
        return {_JSON_KEYS[f]: value(getattr(self, f)) for f in _JSON_KEYS}

    @classmethod
    def from_json(cls, d: dict, value=lambda v: v) -> BothFits:
        return cls(**{f: value(d[k]) for f, k in _JSON_KEYS.items()})


@dataclass(frozen=True)
class NetworkBeyond:
    """A fit's network part against the training range on one reference, mean over the seeds
    of a cell (N; None where no sample leaves the range): its peak |force| beyond and within the
    range and the rms of the whole model's force error beyond it."""

    network_peak_beyond_n: float | None
    network_peak_within_n: float | None
    error_beyond_rms_n: float | None


@dataclass(frozen=True)
class Interval:
    """A mean with its interval [low, high] (units of the quantity)."""

    mean: float
    low: float
    high: float


@dataclass(frozen=True)
class CellStats:
    """One cell of the map (case, n_l, direction) over its paired seeds: the MAE per seed of
    both fits (m), the LIP's mean MAE (m), the paired log ratio, the difference of the MAEs (m)
    with its interval, the verdict, the networks beyond the range, the LIP's force error there
    (N), counts of capped and unconverged fits, and (extrapolation cells only) Holm's p."""

    case: str
    hidden: int
    direction: str
    reference: str
    seeds: tuple[int, ...]
    mae: BothFits[tuple[float, ...]]
    mae_lip_mean: float
    ratio: LogRatio
    difference_m: Interval
    verdict: str
    network: BothFits[NetworkBeyond]
    lip_error_beyond_rms_n: float | None
    capped_fits: int
    unconverged_fits: int
    p_holm: float | None = None
    holm_significant: bool | None = None

    @property
    def label(self) -> str:
        return f"{self.direction} ({self.reference}) / {self.case} / n_l={self.hidden}"

    @property
    def mae_mean(self) -> BothFits[float]:
        return BothFits(*(float(np.mean(v)) for v in (self.mae.unregularized,
                                                       self.mae.regularized)))

    @property
    def outside(self) -> bool:
        """Whether the cell's reference leaves the training range."""
        return self.direction != "inside"

    def to_json(self) -> dict:
        ratio = dataclasses.asdict(self.ratio)
        if self.p_holm is not None:
            ratio["p_holm"] = self.p_holm
        out = {"case": self.case, "hidden": self.hidden, "direction": self.direction,
               "reference": self.reference, "n_seeds": len(self.seeds), "seeds": list(self.seeds)}
        for f, key in _JSON_KEYS.items():
            a = list(getattr(self.mae, f))
            out[f"mae_{key}"] = {"mean": float(np.mean(a)), "per_seed": a}
        out.update({
            "mae_lip": {"mean": self.mae_lip_mean}, "ratio": ratio,
            "difference_m": dataclasses.asdict(self.difference_m), "verdict": self.verdict,
            "network": self.network.to_json(dataclasses.asdict),
            "lip_error_beyond_rms_n": self.lip_error_beyond_rms_n,
            "capped_fits": self.capped_fits, "unconverged_fits": self.unconverged_fits})
        if self.holm_significant is not None:
            out["holm_significant"] = self.holm_significant
        return out

    @classmethod
    def from_json(cls, d: dict) -> CellStats:
        ratio = {f.name: d["ratio"][f.name] for f in dataclasses.fields(LogRatio)}
        return cls(
            case=d["case"], hidden=d["hidden"], direction=d["direction"],
            reference=d["reference"], seeds=tuple(d["seeds"]),
            mae=BothFits(**{f: tuple(d[f"mae_{k}"]["per_seed"]) for f, k in _JSON_KEYS.items()}),
            mae_lip_mean=d["mae_lip"]["mean"], ratio=LogRatio(**ratio),
            difference_m=Interval(**d["difference_m"]), verdict=d["verdict"],
            network=BothFits.from_json(d["network"], lambda v: NetworkBeyond(**v)),
            lip_error_beyond_rms_n=d["lip_error_beyond_rms_n"], capped_fits=d["capped_fits"],
            unconverged_fits=d["unconverged_fits"], p_holm=d["ratio"].get("p_holm"),
            holm_significant=d.get("holm_significant"))


@dataclass(frozen=True)
class ThetaDrift:
    """theta_phy - theta_LIP of one parameter over the seeds of a cell (SI units): mean, sample
    std, and the force it moves at the edge of the training range (N)."""

    mean: float
    std: float
    edge_force_n: float


@dataclass(frozen=True)
class Drift:
    """The parameter drift of a case and n_l: the LIP's mean theta (SI units) and each fit's
    :class:`ThetaDrift` per parameter name."""

    theta_lip: dict[str, float]
    theta: BothFits[dict[str, ThetaDrift]]

    def to_json(self) -> dict:
        return {"theta_lip": self.theta_lip, **self.theta.to_json(
            lambda d: {k: dataclasses.asdict(v) for k, v in d.items()})}

    @classmethod
    def from_json(cls, d: dict) -> Drift:
        return cls(theta_lip=d["theta_lip"], theta=BothFits.from_json(
            d, lambda x: {k: ThetaDrift(**v) for k, v in x.items()}))


@dataclass(frozen=True)
class FitRow:
    """How one PGNN fit of the map stopped: its cell, lambda, stop reason, iterations, costs
    (N**2), last gradient norm and the number of starts."""

    case: str
    hidden: int
    seed: int
    lam: float
    stop: str
    iterations: int
    data_cost: float
    reg_cost: float
    grad_norm: float | None
    restarts: int | None

    def to_json(self) -> dict:
        return {FILE_KEYS.get(k, k): v for k, v in dataclasses.asdict(self).items()}

    @classmethod
    def from_json(cls, d: dict) -> FitRow:
        return cls(**{LAMBDA_KEYS.get(k, k): v for k, v in d.items()})


@dataclass(frozen=True)
class CellFailure:
    """A cell (case, n_l, seed) that raised, with its one-line error."""

    case: str
    hidden: int
    seed: int
    error: str


@dataclass(frozen=True)
class Mechanism:
    """Spearman's rank correlation over ``n_cells`` extrapolation cells of the log MAE ratio with
    the log ratio of the force error beyond the range (None for fewer than 3 cells)."""

    n_cells: int
    spearman: float | None


@dataclass(frozen=True)
class FailureMapResult:
    """The failure map: its settings, how the intervals were computed, the cells (case x n_l x
    direction, ``inside`` last per case and n_l), the drift per (case, n_l), every fit, the
    failed cells and the mechanism; wall time (s), workers and code version of the run that
    computed it (None until the run sets them)."""

    settings: FailureMapSettings
    interval: str
    cells: tuple[CellStats, ...]
    drift: dict[tuple[str, int], Drift]
    fits: tuple[FitRow, ...]
    failures: tuple[CellFailure, ...]
    mechanism: Mechanism
    wall_time_s: float | None = None
    workers: int | None = None
    code_version: str | None = None

    @property
    def outside(self) -> list[CellStats]:
        return [c for c in self.cells if c.outside]

    @property
    def inside(self) -> list[CellStats]:
        return [c for c in self.cells if not c.outside]

    @property
    def region(self) -> dict[str, list[str]]:
        return {v: [c.label for c in self.outside if c.verdict == v] for v in VERDICTS}

    @property
    def fit_stops(self) -> dict[str, int]:
        return {s: sum(f.stop == s for f in self.fits) for s in sorted({f.stop for f in
                                                                       self.fits})}

    @property
    def capped_fits(self) -> int:
        return sum(f.stop == "max_iter" for f in self.fits)

    @property
    def unconverged_fits(self) -> int:
        return sum(f.stop != "converged" for f in self.fits)

    def to_json(self) -> dict:
        """``failure_map.json``."""
        return {
            "settings": to_plain(self.settings), "interval": self.interval,
            "cells": [c.to_json() for c in self.cells], "region": self.region,
            "drift": {f"{case}/{hidden}": d.to_json() for (case, hidden), d in
                      self.drift.items()},
            "fits": [f.to_json() for f in self.fits], "fit_stops": self.fit_stops,
            "capped_fits": self.capped_fits, "unconverged_fits": self.unconverged_fits,
            "failures": [dataclasses.asdict(f) for f in self.failures],
            "mechanism": dataclasses.asdict(self.mechanism), "wall_time_s": self.wall_time_s,
            "workers": self.workers, "code_version": self.code_version}

    @classmethod
    def from_json(cls, d: dict) -> FailureMapResult:
        """From a stored ``failure_map.json`` (its derived counts are recomputed)."""
        def drift_key(key: str) -> tuple[str, int]:
            case, hidden = key.rsplit("/", 1)
            return case, int(hidden)

        return cls(
            settings=build(FailureMapSettings, d["settings"], "failure_map.json: settings"),
            interval=d["interval"], cells=tuple(CellStats.from_json(c) for c in d["cells"]),
            drift={drift_key(k): Drift.from_json(v) for k, v in d["drift"].items()},
            fits=tuple(FitRow.from_json(f) for f in d["fits"]),
            failures=tuple(CellFailure(**f) for f in d["failures"]),
            mechanism=Mechanism(**d["mechanism"]), wall_time_s=d.get("wall_time_s"),
            workers=d.get("workers"), code_version=d.get("code_version"))
