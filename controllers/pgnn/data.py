"""The data a PGNN is fitted on: the filtered, aligned and decimated columns of a record.

Plain numpy (no torch), so that a process prepares the data of its fits and hands them to the
fit workers (:func:`experiments.processes.workers.map_fits`) before it loads torch itself: the
workers start while it would otherwise still be importing. Why the columns are filtered and
decimated: :mod:`controllers.pgnn.model`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clm_sim.features import FeatureMap, edge_force, lip_regressors
from controllers.pgnn_settings import decimation_for


@dataclass(frozen=True)
class TrainingData:
    """Fitting data: physical columns ``phi`` (N, 4) = filtered [a, v, sign v, y] (SI units), the
    network's inputs (the same columns), the filtered force ``target`` (N,) and the sample time
    ``ts`` (s) of the record they came from (``None``: unknown)."""

    phi: np.ndarray
    target: np.ndarray
    ts: float | None = None

    def split(self, fraction: float) -> tuple[TrainingData, TrainingData | None]:
        """The first ``1 - fraction`` for fitting, the last ``fraction`` (contiguous) held out."""
        if fraction <= 0:
            return self, None
        n = len(self.target) - round(fraction * len(self.target))
        return (TrainingData(self.phi[:n], self.target[:n], self.ts),
                TrainingData(self.phi[n:], self.target[n:], self.ts))


def training_data(features: FeatureMap, *, y: np.ndarray, u: np.ndarray, ts: float,
                  decimation: int | None = None) -> TrainingData:
    """Filtered, aligned and decimated fitting data from positions ``y`` (m) and inputs ``u`` (N);
    ``decimation`` None: one sample per 8 ms (:func:`controllers.pgnn_settings.decimation_for`)."""
    decimation = decimation_for(ts, decimation)
    yf, v, a = features.motion(y, ts)
    cols = np.column_stack([lip_regressors(yf, v, a), edge_force(u)])
    keep = features.fit_slice(len(yf))
    cols = features.regression_filter(cols, ts)[keep][::decimation]
    return TrainingData(phi=np.ascontiguousarray(cols[:, :4]), target=cols[:, 4].copy(),
                        ts=float(ts))
