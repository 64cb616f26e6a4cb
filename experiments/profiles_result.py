"""What the identifiability figure draws of the profiles study, as typed values read from the
study's record (:func:`experiments.studies.profiles.summarize`, ``identifiability.json``'s
``"sizes"``). The record's keys that the figure needs are read only here, in ``from_json``;
:func:`experiments.plots.identifiability_figure` reads fields.
"""

from __future__ import annotations

from dataclasses import dataclass

from clm_sim.plant import THETA_NAMES


@dataclass(frozen=True)
class ProfileCurve:
    """One parameter's profile: the values held (SI units) with their data costs (N²), in the
    record's order, and the search bounds [low, high] of the continuation."""

    values: tuple[float, ...]
    data_costs: tuple[float, ...]
    bound: tuple[float, float]

    @classmethod
    def from_json(cls, d: dict) -> ProfileCurve:
        pts = d["profile"]
        return cls(tuple(p["value"] for p in pts), tuple(p["data_cost"] for p in pts),
                   tuple(d["bound"]))


@dataclass(frozen=True)
class MarkedFit:
    """A fit of the study's table drawn on the profiles: its λ, data cost (N²) and θ_phy."""

    lam: float
    data_cost: float
    theta: dict[str, float]

    @classmethod
    def from_json(cls, d: dict) -> MarkedFit:
        return cls(d["lambda"], d["data_cost"], d["theta"])


@dataclass(frozen=True)
class SizeProfiles:
    """The profiles of one network size: the best data cost (N²), the threshold δ (N²), each
    parameter's curve and the fits to mark."""

    best_data_cost: float
    delta: float
    curves: dict[str, ProfileCurve]
    fits: tuple[MarkedFit, ...]

    @classmethod
    def from_json(cls, rec: dict) -> SizeProfiles:
        return cls(rec["best_data_cost"], rec["delta"],
                   {name: ProfileCurve.from_json(rec["parameters"][name])
                    for name in THETA_NAMES},
                   tuple(MarkedFit.from_json(f) for f in rec["fits"]))


def sizes_from_json(sizes: dict) -> dict[str, SizeProfiles]:
    """``{n_l: SizeProfiles}`` of the study's record per network size (keys kept in order)."""
    return {key: SizeProfiles.from_json(rec) for key, rec in sizes.items()}
