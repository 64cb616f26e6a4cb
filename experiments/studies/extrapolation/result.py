"""The extrapolation study's result as typed values, and the one mapping to and from
``study.json``.

:func:`experiments.studies.extrapolation.study._summarize` builds an :class:`ExtrapolationResult`;
the report and the figures (:mod:`experiments.studies.extrapolation.figures`) read its fields. The
file's names of the variants (``"lambda=0.01"``, ``"sequential"``, ``"LIP"``,
``"feedback only"``) are made only by :func:`variant_key` and the constants here, and its other
keys appear only in the ``to_json``/``from_json`` methods.
"""

from __future__ import annotations

from dataclasses import dataclass

from clm_sim.features import TrainingRange
from controllers.pgnn_settings import FILE_KEYS

FEEDBACK = "feedback only"
LIP = "LIP"
SEQUENTIAL = "sequential"


def variant_key(lam: float) -> str:
    """The name of the simultaneous PGNN trained with ``lam`` (``lambda=0.01``)."""
    return f"lambda={lam:g}"


def variant_label(key: str) -> str:
    """A variant's name in figures and text (``lambda=0.01`` -> ``λ = 0.01``)."""
    return key.replace("lambda=", "λ = ")


@dataclass(frozen=True)
class Spread:
    """One quantity over the training seeds: mean, sample std (0 for one seed) and the values."""

    mean: float
    std: float
    per_seed: tuple[float, ...]

    def to_json(self) -> dict:
        return {"mean": self.mean, "std": self.std, "per_seed": list(self.per_seed)}

    @classmethod
    def from_json(cls, d: dict) -> Spread:
        return cls(d["mean"], d["std"], tuple(d["per_seed"]))


@dataclass(frozen=True)
class NetworkParts:
    """A PGNN variant's parts on one reference, mean over seeds (N; None where no sample leaves
    the training range): the network force's peak and rms, its peak beyond and within the range,
    the fraction of samples beyond it, and the rms of the whole model's force minus the true
    plant force over the samples beyond it."""

    network_max_abs_n: float
    network_rms_n: float
    network_max_abs_beyond_n: float | None
    network_max_abs_within_n: float | None
    fraction_beyond: float
    model_error_beyond_rms_n: float | None

    def to_json(self) -> dict:
        return {"network_max_abs_n": self.network_max_abs_n,
                "network_rms_n": self.network_rms_n,
                "network_max_abs_beyond_n": self.network_max_abs_beyond_n,
                "network_max_abs_within_n": self.network_max_abs_within_n,
                "fraction_beyond": self.fraction_beyond,
                "model_error_beyond_rms_n": self.model_error_beyond_rms_n}

    @classmethod
    def from_json(cls, d: dict) -> NetworkParts:
        return cls(d["network_max_abs_n"], d["network_rms_n"], d["network_max_abs_beyond_n"],
                   d["network_max_abs_within_n"], d["fraction_beyond"],
                   d["model_error_beyond_rms_n"])


@dataclass(frozen=True)
class Costs:
    """The two terms of a fit's cost at its end, mean over seeds (N²)."""

    data: float
    deviation: float


@dataclass(frozen=True)
class Trained:
    """What a trained PGNN variant adds to its MAE: θ_phy per seed and its mean (SI units), the
    final cost terms, the LM iterations per seed and its parts per reference."""

    theta_phy_per_seed: tuple[dict[str, float], ...]
    theta_phy: dict[str, float]
    cost: Costs
    iterations: tuple[int, ...]
    parts: dict[str, NetworkParts]


@dataclass(frozen=True)
class Variant:
    """One row of the study: MAE (m) per reference over seeds; ``trained`` for a PGNN (None for
    feedback only and the LIP); ``lip_error_beyond_rms_n`` for the LIP only (N, per reference
    that leaves the training range)."""

    mae: dict[str, Spread]
    trained: Trained | None = None
    lip_error_beyond_rms_n: dict[str, float] | None = None

    def to_json(self) -> dict:
        out: dict = {"mae": {r: s.to_json() for r, s in self.mae.items()}}
        if self.trained is not None:
            t = self.trained
            out.update({"theta_phy_per_seed": list(t.theta_phy_per_seed),
                        "theta_phy": t.theta_phy,
                        "cost": {"data": t.cost.data, "deviation": t.cost.deviation},
                        "iterations": list(t.iterations),
                        "parts": {r: p.to_json() for r, p in t.parts.items()}})
        if self.lip_error_beyond_rms_n is not None:
            out["model_error_beyond_rms_n"] = self.lip_error_beyond_rms_n
        return out

    @classmethod
    def from_json(cls, d: dict) -> Variant:
        trained = None
        if "theta_phy" in d:
            trained = Trained(tuple(d["theta_phy_per_seed"]), d["theta_phy"],
                              Costs(d["cost"]["data"], d["cost"]["deviation"]),
                              tuple(d["iterations"]),
                              {r: NetworkParts.from_json(p) for r, p in d["parts"].items()})
        return cls({r: Spread.from_json(s) for r, s in d["mae"].items()}, trained,
                   d.get("model_error_beyond_rms_n"))


@dataclass(frozen=True)
class ExtrapolationResult:
    """The study's summary: the λ sweep (sorted), the λ compared with 0, n_l, seeds, the training
    reference and those leaving its range, θ_LIP (SI units) with its rms residual (N), the range
    each reference covers, and every variant by name (PGNN variants first, sequential first,
    then feedback only and the LIP; names from :func:`variant_key` and the constants)."""

    lams: tuple[float, ...]
    paper_lam: float
    hidden: int
    seeds: int
    inside: str
    outside: tuple[str, ...]
    theta_lip: dict[str, float]
    lip_residual_rms_n: float
    ranges: dict[str, TrainingRange]
    variants: dict[str, Variant]

    @property
    def references(self) -> tuple[str, ...]:
        """The training reference, then those that leave its range."""
        return (self.inside, *self.outside)

    @property
    def lam_keys(self) -> list[str]:
        """The names of the simultaneous PGNN variants, in the order of the sweep."""
        return [variant_key(lam) for lam in self.lams]

    @property
    def unregularized(self) -> Variant:
        return self.variants[variant_key(0.0)]

    @property
    def regularized(self) -> Variant:
        """The simultaneous PGNN with the paper's λ."""
        return self.variants[variant_key(self.paper_lam)]

    def to_json(self) -> dict:
        return {FILE_KEYS["lams"]: list(self.lams), FILE_KEYS["paper_lam"]: self.paper_lam,
                "hidden": self.hidden, "seeds": self.seeds, "inside": self.inside,
                "outside": list(self.outside),
                "theta_lip": self.theta_lip, "lip_residual_rms_n": self.lip_residual_rms_n,
                "ranges": {r: v.as_dict() for r, v in self.ranges.items()},
                "variants": {k: v.to_json() for k, v in self.variants.items()}}

    @classmethod
    def from_json(cls, d: dict) -> ExtrapolationResult:
        return cls(tuple(d[FILE_KEYS["lams"]]), d[FILE_KEYS["paper_lam"]], d["hidden"], d["seeds"], d["inside"],
                   tuple(d["outside"]), d["theta_lip"], d["lip_residual_rms_n"],
                   {r: TrainingRange(**v) for r, v in d["ranges"].items()},
                   {k: Variant.from_json(v) for k, v in d["variants"].items()})
