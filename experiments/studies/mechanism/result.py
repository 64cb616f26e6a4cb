"""The mechanism study's result (``mechanism.json``) as typed values, and the one mapping to and
from JSON: a cell's fits and LIP (:mod:`experiments.studies.mechanism.cells` makes them) and the
whole result (:mod:`experiments.studies.mechanism.summary` summarizes the cells)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from clm_sim.schema import build, to_plain
from controllers.pgnn_settings import FILE_KEYS
from experiments.studies.mechanism.settings import MechanismSettings


@dataclass(frozen=True)
class EffectBeyond:
    """The rms force (N) of one plant effect that the LIP's columns do not hold: on the inside
    reference, and along the outside one beyond the range."""

    inside_rms_n: float
    beyond_rms_n: float

    def to_json(self) -> dict:
        return {"inside_rms_n": self.inside_rms_n, "beyond_rms_n": self.beyond_rms_n}

    @classmethod
    def from_json(cls, d: dict) -> EffectBeyond:
        return cls(d["inside_rms_n"], d["beyond_rms_n"])


@dataclass(frozen=True)
class CellLip:
    """A record's LIP: θ, its static force error beyond the range (rms, N), its force error
    along the outside reference beyond the range and the rms of the command needed there (N),
    and its MAE per reference (m)."""

    theta: dict[str, float]
    error_beyond_rms_n: float
    error_along_rms_n: float
    need_along_rms_n: float
    mae: dict[str, float]

    def to_json(self) -> dict:
        return {"theta": self.theta, "error_beyond_rms_n": self.error_beyond_rms_n,
                "error_along_rms_n": self.error_along_rms_n,
                "need_along_rms_n": self.need_along_rms_n, "mae": self.mae}

    @classmethod
    def from_json(cls, d: dict) -> CellLip:
        return cls(d["theta"], d["error_beyond_rms_n"], d["error_along_rms_n"],
                   d["need_along_rms_n"], d["mae"])


@dataclass(frozen=True)
class StaticSplit:
    """A PGNN's static force (N, on the cell's position grid) in parts: θ·T, the network, the
    network's best linear-in-features part and its remainder."""

    physical: list[float]
    network: list[float]
    network_linear: list[float]
    remainder: list[float]

    def to_json(self) -> dict:
        return {"physical": self.physical, "network": self.network,
                "network_linear": self.network_linear, "remainder": self.remainder}

    @classmethod
    def from_json(cls, d: dict) -> StaticSplit:
        return cls(d["physical"], d["network"], d["network_linear"], d["remainder"])


@dataclass(frozen=True)
class Fit:
    """One PGNN fit of a cell (a draw at one lambda): its stop, θ, MAE per reference (m), the
    static force errors beyond the range (rms, N; below and above it), the force error along
    the outside reference, the force at the far dwell, the stiffness drift, the network's
    linear part, the cubic coefficients of its remainder and of the whole model (N/m³), the
    static split and, with ``near_linear``, the unit-by-unit view
    (:mod:`experiments.studies.mechanism.units`)."""

    draw: int
    lam: float
    stop: str
    iterations: int
    data_cost: float
    theta: dict[str, float]
    mae: dict[str, float]
    error_beyond_rms_n: float
    error_beyond_sides_rms_n: list[float]
    error_along_rms_n: float
    dwell_force_n: float
    drift_stiffness: float
    network_linear: dict[str, float]
    remainder_cubic: float
    model_cubic: float
    static: StaticSplit
    units: dict | None = None

    def to_json(self) -> dict:
        out = {"draw": self.draw, FILE_KEYS["lam"]: self.lam, "stop": self.stop,
               "iterations": self.iterations, "data_cost": self.data_cost, "theta": self.theta,
               "mae": self.mae, "error_beyond_rms_n": self.error_beyond_rms_n,
               "error_beyond_sides_rms_n": self.error_beyond_sides_rms_n,
               "error_along_rms_n": self.error_along_rms_n,
               "dwell_force_n": self.dwell_force_n, "drift_stiffness": self.drift_stiffness,
               "network_linear": self.network_linear, "remainder_cubic": self.remainder_cubic,
               "model_cubic": self.model_cubic, "static": self.static.to_json()}
        if self.units is not None:
            out["units"] = self.units
        return out

    @classmethod
    def from_json(cls, d: dict) -> Fit:
        return cls(d["draw"], d[FILE_KEYS["lam"]], d["stop"], d["iterations"], d["data_cost"],
                   d["theta"], d["mae"], d["error_beyond_rms_n"], d["error_beyond_sides_rms_n"],
                   d["error_along_rms_n"], d["dwell_force_n"], d["drift_stiffness"],
                   d["network_linear"], d["remainder_cubic"], d["model_cubic"],
                   StaticSplit.from_json(d["static"]), d.get("units"))


@dataclass(frozen=True)
class CellResult:
    """One (case, training record): the training range's position limit (m), the force of each
    effect the LIP does not hold, the static curves on the position grid ``y`` (m: the true
    force, the LIP's), the LIP, the truth's cubic coefficient (N/m³) and every fit."""

    case: str
    record: int
    position_limit_m: float
    effects_beyond: dict[str, EffectBeyond]
    y: list[float]
    truth: list[float]
    lip_static: list[float]
    lip: CellLip
    truth_cubic: float
    fits: tuple[Fit, ...]

    def to_json(self) -> dict:
        return {"case": self.case, "record": self.record,
                "position_limit_m": self.position_limit_m,
                "effects_beyond": {k: e.to_json() for k, e in self.effects_beyond.items()},
                "y": self.y, "truth": self.truth, "lip_static": self.lip_static,
                "lip": self.lip.to_json(), "truth_cubic": self.truth_cubic,
                "fits": [f.to_json() for f in self.fits]}

    @classmethod
    def from_json(cls, d: dict) -> CellResult:
        return cls(d["case"], d["record"], d["position_limit_m"],
                   {k: EffectBeyond.from_json(e) for k, e in d["effects_beyond"].items()},
                   d["y"], d["truth"], d["lip_static"], CellLip.from_json(d["lip"]),
                   d["truth_cubic"], tuple(map(Fit.from_json, d["fits"])))


def _plain(cls, d: dict):
    """``cls`` from its JSON mapping whose keys are its field names."""
    return cls(**d)


@dataclass(frozen=True)
class MaeDifference:
    """MAE on the outside reference, lambda − 0 (m) over records x draws: the mean and its
    two-level bootstrap interval, the per-record means, the pairs where lambda is lower and all
    pairs, the t-test's p on the per-record means and its t-interval, and p after Holm."""

    mean: float
    ci: list[float]
    per_record: list[float]
    lam_lower: int
    n: int
    p_records_t: float | None
    ci_records_t: list[float] | None
    p_holm: float | None = None

    def to_json(self) -> dict:
        return dataclasses.asdict(self)

    from_json = classmethod(_plain)


@dataclass(frozen=True)
class Ratio:
    """MAE on the outside reference, lambda / 0: the ratio and its bootstrap interval."""

    ratio: float
    ci: list[float]

    def to_json(self) -> dict:
        return dataclasses.asdict(self)

    from_json = classmethod(_plain)


@dataclass(frozen=True)
class ForceDifference:
    """Static force error beyond the range, lambda − 0 (N): mean with its bootstrap interval,
    the median of the pairs, how many are above zero, and the pairs."""

    mean: float
    ci: list[float]
    median: float
    higher: int
    n: int

    def to_json(self) -> dict:
        return dataclasses.asdict(self)

    from_json = classmethod(_plain)


@dataclass(frozen=True)
class WorstFit:
    """The fit with the largest static force error beyond the range: its record, draw and
    lambda, the error (rms, N; below and above the range), its MAE on the outside reference
    (µm) and its force error along it beyond the range (N)."""

    record: int
    draw: int
    lam: float
    rms_n: float
    sides_rms_n: list[float]
    mae_outside_um: float
    error_along_rms_n: float

    def to_json(self) -> dict:
        return {"record": self.record, "draw": self.draw, FILE_KEYS["lam"]: self.lam,
                "rms_n": self.rms_n, "sides_rms_n": self.sides_rms_n,
                "mae_outside_um": self.mae_outside_um,
                "error_along_rms_n": self.error_along_rms_n}

    @classmethod
    def from_json(cls, d: dict) -> WorstFit:
        return cls(d["record"], d["draw"], d[FILE_KEYS["lam"]], d["rms_n"], d["sides_rms_n"],
                   d["mae_outside_um"], d["error_along_rms_n"])


@dataclass(frozen=True)
class RowSummary:
    """One row (lambda = 0 or lambda) of a case: medians over its fits of the MAE (µm), the
    force errors (N), the force at the far dwell (N), the stiffness drift, the network's slope
    and their sum (N/m), the cubic coefficients (N/m³), how far each parameter of θ moved, and
    how many fits converged of how many."""

    mae_inside_um: float
    mae_outside_um: float
    error_beyond_rms_n: float
    error_along_rms_n: float
    dwell_force_n: float
    drift_stiffness: float
    network_linear_stiffness: float
    model_linear_stiffness_minus_lip: float
    remainder_cubic: float
    model_cubic: float
    theta_moved: dict[str, float]
    converged: int
    fits: int

    def to_json(self) -> dict:
        return dataclasses.asdict(self)

    from_json = classmethod(_plain)


@dataclass(frozen=True)
class LipSummary:
    """The LIP of a case, medians over its records: MAE inside and outside (µm), the static
    force error beyond the range, the force error along the outside reference and the rms of
    the command needed there (N)."""

    mae_inside_um: float
    mae_outside_um: float
    error_beyond_rms_n: float
    error_along_rms_n: float
    need_along_rms_n: float

    def to_json(self) -> dict:
        return dataclasses.asdict(self)

    from_json = classmethod(_plain)


@dataclass(frozen=True)
class UnitsRow:
    """The unit-by-unit view of one row (:func:`experiments.studies.mechanism.summary.
    units_summary`): named units (median, range), fits with named units of all fits, the named
    units' share of the remainder beyond the range, and medians of the static error beyond and
    inside (N), its change per arm (N) and the MAE outside (µm) per arm (none: the fit itself;
    named; control), and in how many fits the named arm lowers the error more."""

    named_median: float
    named_range: list[int]
    fits_with_named: int
    fits: int
    named_share_beyond: float
    error_beyond_none_n: float
    error_beyond_named_n: float | None
    error_beyond_control_n: float | None
    error_inside_none_n: float | None
    error_inside_named_n: float | None
    error_inside_control_n: float | None
    delta_beyond_named_n: float | None
    delta_beyond_control_n: float | None
    mae_outside_named_um: float | None
    mae_outside_control_um: float | None
    mae_outside_none_um: float | None
    named_lowers_more: int

    def to_json(self) -> dict:
        return dataclasses.asdict(self)

    from_json = classmethod(_plain)


@dataclass(frozen=True)
class Outcome:
    """The prediction written before the run (``predicted``: the config's numbers, µm and N,
    and ``factor``) beside what the run measured, and which parts held."""

    predicted: dict[str, float]
    measured_mae_diff_um: float
    measured_ci_um: list[float]
    sign_held: bool
    amount_held: bool
    measured_error_beyond_lambda0_n: float
    measured_error_beyond_lambda_n: float
    error_beyond_lambda0_held: bool
    error_beyond_lambda_held: bool
    calibrated_amount_held: bool | None = None

    @property
    def mae_diff_um(self) -> float:
        return self.predicted["mae_diff_um"]

    @property
    def mae_diff_calibrated_um(self) -> float | None:
        return self.predicted.get("mae_diff_calibrated_um")

    @property
    def error_beyond_lambda0_n(self) -> float:
        return self.predicted["error_beyond_lambda0_n"]

    @property
    def error_beyond_lambda_n(self) -> float:
        return self.predicted[FILE_KEYS["error_beyond_lam_n"]]

    @property
    def factor(self) -> float:
        return self.predicted["factor"]

    def to_json(self) -> dict:
        out = {**self.predicted, **{k: getattr(self, k) for k in _MEASURED[:-1]}}
        if self.calibrated_amount_held is not None:
            out["calibrated_amount_held"] = self.calibrated_amount_held
        return out

    @classmethod
    def from_json(cls, d: dict) -> Outcome:
        return cls({k: v for k, v in d.items() if k not in _MEASURED},
                   **{k: d[k] for k in _MEASURED if k in d})


_MEASURED = tuple(f.name for f in dataclasses.fields(Outcome))[1:]  # what the run measured


@dataclass(frozen=True)
class CaseSummary:
    """Finding (iii) and its mechanism for one case: the plant's effects (as configured), the
    truth's cubic coefficient (N/m³) and far-dwell force (N), the records and draws, the MAE
    difference and ratio, the force error difference, Spearman's rho between MAE and force
    error over the fits, the worst fit, the rows (lambda = 0, lambda), the LIP, each effect's
    force the LIP does not hold, and, when set, the unit-by-unit view and the prediction."""

    effects: list[dict]
    truth_cubic: float
    truth_dwell_force_n: float
    records: list[int]
    draws: int
    mae_outside_diff: MaeDifference
    mae_outside_ratio: Ratio
    error_beyond_diff: ForceDifference
    spearman_mae_vs_force_error: float
    worst_error_beyond: WorstFit
    rows: dict[str, RowSummary]
    lip: LipSummary
    effects_beyond: dict[str, EffectBeyond]
    units: dict[str, UnitsRow] | None = None
    prediction: Outcome | None = None

    def to_json(self) -> dict:
        out = {"effects": self.effects, "truth_cubic": self.truth_cubic,
               "truth_dwell_force_n": self.truth_dwell_force_n, "records": self.records,
               "draws": self.draws, "mae_outside_diff": self.mae_outside_diff.to_json(),
               "mae_outside_ratio": self.mae_outside_ratio.to_json(),
               "error_beyond_diff": self.error_beyond_diff.to_json(),
               "spearman_mae_vs_force_error": self.spearman_mae_vs_force_error,
               "worst_error_beyond": self.worst_error_beyond.to_json(),
               "rows": {k: r.to_json() for k, r in self.rows.items()},
               "lip": self.lip.to_json(),
               "effects_beyond": {k: e.to_json() for k, e in self.effects_beyond.items()}}
        if self.units is not None:
            out["units"] = {k: u.to_json() for k, u in self.units.items()}
        if self.prediction is not None:
            out["prediction"] = self.prediction.to_json()
        return out

    @classmethod
    def from_json(cls, d: dict) -> CaseSummary:
        return cls(d["effects"], d["truth_cubic"], d["truth_dwell_force_n"], d["records"],
                   d["draws"], MaeDifference.from_json(d["mae_outside_diff"]),
                   Ratio.from_json(d["mae_outside_ratio"]),
                   ForceDifference.from_json(d["error_beyond_diff"]),
                   d["spearman_mae_vs_force_error"],
                   WorstFit.from_json(d["worst_error_beyond"]),
                   {k: RowSummary.from_json(r) for k, r in d["rows"].items()},
                   LipSummary.from_json(d["lip"]),
                   {k: EffectBeyond.from_json(e) for k, e in d["effects_beyond"].items()},
                   None if "units" not in d else
                   {k: UnitsRow.from_json(u) for k, u in d["units"].items()},
                   None if "prediction" not in d else Outcome.from_json(d["prediction"]))


@dataclass(frozen=True)
class MechanismResult:
    """Per case its :class:`CaseSummary` (:func:`experiments.studies.mechanism.summary.
    summarize`), the settings, the wall time (s; None before the run is timed) and every cell
    (one per case and record, in task order)."""

    cases: dict[str, CaseSummary]
    settings: MechanismSettings
    wall_time_s: float | None = None
    cells: tuple[CellResult, ...] = ()

    def to_json(self) -> dict:
        return {"cases": {k: c.to_json() for k, c in self.cases.items()},
                "settings": to_plain(self.settings), "wall_time_s": self.wall_time_s,
                "cells": [c.to_json() for c in self.cells]}

    @classmethod
    def from_json(cls, d: dict) -> MechanismResult:
        return cls({k: CaseSummary.from_json(c) for k, c in d["cases"].items()},
                   build(MechanismSettings, d["settings"], "settings"), d.get("wall_time_s"),
                   tuple(map(CellResult.from_json, d.get("cells", ()))))
