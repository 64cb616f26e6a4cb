"""What one table row computed, typed: per seed the tracking metrics per reference and the fit,
and the row built from them.

    Testbed.evaluate -> RowResult (models, SeedResult per seed) -> TableRow.from_result -> table

:class:`SeedResult` replaces the per-seed dict that carried the fit under a ``"fit"`` key beside
the references; :class:`TableRow` replaces the row dict that ``make_row`` assembled. The files
keep their keys: ``TableRow.row`` is the row of ``table.json``, an :class:`experiments.table.Row`
(the one place its keys are written and read), which the renderers, comparisons, sweeps and
figures take.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from clm_sim.plant import THETA_NAMES
from clm_sim.run import Run
from experiments.config import FeedforwardSpec
from experiments.table import FitSummary, Row, Settings, Stat, regularizers, row_settings

if TYPE_CHECKING:  # the record type, for annotations only
    from controllers.pgnn.fit_record import FitRecord


@dataclass(frozen=True)
class ReferenceMetrics:
    """One replay on one reference: tracking-error MAE, RMS and peak (m); for a PGNN the peak
    network force over the reference and over its samples beyond the training range (N; None
    where no sample leaves the range)."""

    mae: float
    rms: float
    max: float
    network_peak_n: float | None = None
    network_peak_beyond_n: float | None = None

    def to_json(self) -> dict:
        out = {"mae": self.mae, "rms": self.rms, "max": self.max}
        if self.network_peak_n is not None:
            out.update(network_peak_n=self.network_peak_n,
                       network_peak_beyond_n=self.network_peak_beyond_n)
        return out


@dataclass(frozen=True)
class SeedFit:
    """The fit of one seed of a PGNN row: its index, the model's :class:`FitRecord` and the
    largest relative drift of theta_phy from theta_LIP (None where it was not computed)."""

    seed: int
    record: FitRecord
    theta_drift: float | None = None

    def to_json(self) -> dict:
        """One entry of a row's ``"fits"`` in ``table.json``."""
        return self.summary().to_json()

    def summary(self) -> FitSummary:
        return FitSummary.of(self.seed, self.record, self.theta_drift)


def theta_drift(theta: dict[str, float], theta_lip: dict[str, float]) -> float:
    """Largest relative distance ``|theta_k - theta_LIP,k| / |theta_LIP,k|`` over the parameters
    whose LIP value is not zero."""
    return max(abs(theta[k] - theta_lip[k]) / abs(theta_lip[k]) for k in theta if theta_lip[k])


@dataclass(frozen=True)
class SeedResult:
    """One seed of a row: metrics per reference (in the order replayed) and, for a PGNN, its
    fit."""

    references: dict[str, ReferenceMetrics]
    fit: SeedFit | None = None


@dataclass
class RowResult:
    """One table row computed: the fitted models (``[None]`` for feedback only), one
    :class:`SeedResult` per seed and the replays of the first seed."""

    spec: FeedforwardSpec
    models: list
    seeds: list[SeedResult]
    first_replays: dict[str, Run]

    def thetas(self) -> list[dict[str, float]]:
        """theta_phy of every fitted model (named, SI units; none for feedback only)."""
        return [dict(m.theta_) for m in self.models if m is not None]


def _stat(vals) -> Stat:
    vals = np.asarray(vals, dtype=float)
    return Stat(float(vals.mean()), float(vals.std(ddof=1) if len(vals) > 1 else 0.0))


@dataclass(frozen=True)
class TableRow:
    """One row of the results table: the feedforward and its seeds' metrics. ``to_json`` is the
    row of ``table.json`` (keys in :mod:`experiments.table`)."""

    spec: FeedforwardSpec
    seeds: tuple[SeedResult, ...]
    thetas: tuple[dict[str, float], ...] = ()

    @classmethod
    def from_result(cls, result: RowResult) -> TableRow:
        return cls(result.spec, tuple(result.seeds), tuple(result.thetas()))

    @property
    def references(self) -> list[str]:
        return list(self.seeds[0].references)

    @property
    def fits(self) -> list[SeedFit] | None:
        """The fits of a PGNN row, one per seed (None for other rows)."""
        fits = [s.fit for s in self.seeds]
        return None if any(f is None for f in fits) else fits

    def _stat(self, ref: str, key: str) -> Stat:
        return _stat([getattr(s.references[ref], key) for s in self.seeds])

    def to_json(self) -> dict:
        return self.row().to_json()

    def row(self) -> Row:
        """The row as ``table.json`` holds it (:class:`experiments.table.Row`)."""
        spec, refs, thetas = self.spec, self.references, list(self.thetas)
        theta = ({k: float(np.mean([t[k] for t in thetas])) for k in THETA_NAMES}
                 if thetas else None)
        common = dict(
            kind=spec.kind, training=spec.training, lam=spec.lam, hidden=spec.hidden,
            n_seeds=len(self.seeds), label=spec.label(), theta_phy=theta,
            theta_phy_per_seed=thetas or None,
            mae={ref: self._stat(ref, "mae") for ref in refs},
            rms={ref: self._stat(ref, "rms") for ref in refs},
            max={ref: self._stat(ref, "max") for ref in refs},
            mae_per_seed={ref: [s.references[ref].mae for s in self.seeds] for ref in refs})
        fits = self.fits
        if fits is None:
            return Row(**common)
        records = [f.record for f in fits]
        first = self.seeds[0].references
        return Row(**common, regularizers=Settings(regularizers(spec, records)),
                   settings=Settings(row_settings(spec, records)),
                   fits=tuple(f.summary() for f in fits),
                   converged=sum(r.converged for r in records),
                   at_edge=sum(r.at_edge for r in records),
                   data_cost=_stat([r.data_cost for r in records]),
                   reg_cost=_stat([r.reg_cost for r in records]),
                   theta_drift=_stat([f.theta_drift for f in fits]),
                   network_peak_beyond_n={
                       ref: _stat([s.references[ref].network_peak_beyond_n for s in self.seeds])
                       for ref in refs if first[ref].network_peak_beyond_n is not None})


@dataclass(frozen=True)
class ForceSplit:
    """A feedforward's force on one reference, split as the models computed it (for
    :func:`experiments.studies.extrapolation.figures.split_figure`, which draws it and predicts
    nothing).

    reference: its name; ts: sample time (s); r: the reference (m); lip_force: the LIP's force
    (N); parts: variant key -> (physical part theta_phy . filt(T), network part) (N) of one
    model; truth: the true plant force (N; None: unknown); beyond: samples outside the
    training range."""

    reference: str
    ts: float
    r: np.ndarray
    lip_force: np.ndarray
    parts: dict[str, tuple[np.ndarray, np.ndarray]]
    beyond: np.ndarray
    truth: np.ndarray | None = None


@dataclass(frozen=True)
class BeyondRange:
    """A PGNN's force on one reference against the training range, computed once for the
    testbed, the studies and the failure map: the network part's peak |force| over the reference,
    beyond the training range and within it, its rms, the share of samples beyond, and the rms
    of the whole model's force minus the true plant force over the samples beyond (N; None where
    no sample leaves the range or the truth is unknown)."""

    network_peak_n: float
    network_rms_n: float
    network_peak_beyond_n: float | None
    network_peak_within_n: float | None
    fraction_beyond: float
    error_beyond_rms_n: float | None

    @classmethod
    def of(cls, physical: np.ndarray, network: np.ndarray, beyond: np.ndarray,
           truth: np.ndarray | None = None) -> BeyondRange:
        """From the model's physical and network parts (N) on a reference, the mask of its
        samples beyond the training range and the true plant force (N; None: unknown)."""
        net = np.abs(np.asarray(network, dtype=float))
        within = ~beyond
        return cls(
            network_peak_n=float(np.max(net)),
            network_rms_n=float(np.sqrt(np.mean(net ** 2))),
            network_peak_beyond_n=float(np.max(net[beyond])) if beyond.any() else None,
            network_peak_within_n=float(np.max(net[within])) if within.any() else None,
            fraction_beyond=float(beyond.mean()),
            error_beyond_rms_n=None if truth is None else error_beyond_rms(
                np.asarray(physical, dtype=float) + np.asarray(network, dtype=float), truth,
                beyond))


def error_beyond_rms(force: np.ndarray, truth: np.ndarray, beyond: np.ndarray) -> float | None:
    """rms of a model's force minus the true plant force over the samples ``beyond`` the
    training range (N; None where there is none)."""
    return float(np.sqrt(np.mean((force - truth)[beyond] ** 2))) if beyond.any() else None
