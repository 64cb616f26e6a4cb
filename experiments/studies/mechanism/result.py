"""The mechanism study's result (``mechanism.json``) as typed values, and the one mapping to and
from JSON: a cell's fits and LIP (:mod:`experiments.studies.mechanism.cells` makes them) and the
whole result (:mod:`experiments.studies.mechanism.summary` summarizes the cells)."""

from __future__ import annotations

from dataclasses import dataclass


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
        out = {"draw": self.draw, "lambda": self.lam, "stop": self.stop,
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
        return cls(d["draw"], d["lambda"], d["stop"], d["iterations"], d["data_cost"],
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


@dataclass(frozen=True)
class MechanismResult:
    """Per case its summary (:func:`experiments.studies.mechanism.summary.summarize`: finding
    (iii) with its intervals and Holm-adjusted p, the mechanism's medians), the settings as the
    config names them, the wall time (s; None before the run is timed) and every cell (one per
    case and record, in task order)."""

    cases: dict[str, dict]
    settings: dict
    wall_time_s: float | None = None
    cells: tuple[CellResult, ...] = ()

    def to_json(self) -> dict:
        return {"cases": self.cases, "settings": self.settings,
                "wall_time_s": self.wall_time_s, "cells": [c.to_json() for c in self.cells]}

    @classmethod
    def from_json(cls, d: dict) -> MechanismResult:
        return cls(d["cases"], d["settings"], d.get("wall_time_s"),
                   tuple(map(CellResult.from_json, d.get("cells", ()))))
