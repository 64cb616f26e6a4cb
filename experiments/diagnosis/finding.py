"""What the diagnosis says: frozen result types with one rendering each.

A :class:`Finding` is one named cause: its effect (the candidate family's name), its parameters as
:class:`Estimate` (value, standard error where the fit gives one, SI unit) and the fraction of the
residual it explains. :class:`Unexplained` is the part of the residual that the significance rule
says is there but that no admissible family names. ``Diagnosis.summary()`` renders both; the
CLI, the emulated machine and the report all print that one rendering.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import MappingProxyType
from typing import Mapping

from clm_sim.effects.base import Effect


def _num(x: float) -> str:
    return f"{x:.4g}"


@dataclass(frozen=True)
class Estimate:
    """A parameter estimate: ``value`` in ``unit`` (SI), ``std`` its standard error (None where
    the code cannot estimate one: a searched nonlinear parameter, or one derived from several
    coefficients), ``model`` the model's own value where the estimate corrects one."""

    value: float
    std: float | None = None
    unit: str = ""
    model: float | None = None

    def __float__(self) -> float:
        return float(self.value)

    def __str__(self) -> str:
        s = _num(self.value)
        if self.std is not None and math.isfinite(self.std):
            s += f" ± {self.std:.2g}"
        if self.unit:
            s += f" {self.unit}"
        return s if self.model is None else f"{_num(self.model)} -> {s}"

    def to_json(self) -> dict:
        out = {"value": float(self.value), "unit": self.unit}
        if self.std is not None:
            out["std"] = float(self.std)
        if self.model is not None:
            out["model"] = float(self.model)
        return out


@dataclass(frozen=True)
class Finding:
    """One named cause.

    effect: the family's name (``cogging``, ``force_offset``, ``parameter_mismatch``, ...).
    parameters: name -> :class:`Estimate`, in SI units. explained_fraction: the held-out MSE drop
    when the cause joined the model (in selection order), over the held-out MSE of the model's
    own residual; the fractions of a diagnosis add up to the total explained. unique_fraction: the
    rise when it alone is left out of the final model. effect_object: the :class:`Effect` that
    extends the model (None for a parameter mismatch and ``not_supported``); model_effect: for
    ``not_supported``, the model's effect that the data does not hold. n_params: the parameters
    of the explanation (linear coefficients and searched ones), as the parsimony rule counts.
    """

    effect: str
    parameters: Mapping[str, Estimate]
    explained_fraction: float
    unique_fraction: float = 0.0
    selection_gain: float = 0.0
    folds_improved: int = 0
    p_value: float = 1.0
    n_params: int = 0
    effect_object: Effect | None = None
    model_effect: Effect | None = None

    def __post_init__(self):
        object.__setattr__(self, "parameters", MappingProxyType(dict(self.parameters)))

    def __str__(self) -> str:
        what = self.effect
        if self.model_effect is not None:
            what += f" (model's {self.model_effect.type})"
        params = ", ".join(f"{k} {v}" for k, v in self.parameters.items())
        return f"{what}: {params or 'no parameter beyond its uncertainty'} " \
               f"(explains {100 * self.explained_fraction:.1f} %)"

    def __repr__(self) -> str:
        return f"Finding({self.effect!r}, explained={self.explained_fraction:.3g})"

    def values(self) -> dict[str, float]:
        """The parameters' estimates as floats, by name."""
        return {k: float(v.value) for k, v in self.parameters.items()}

    def to_json(self) -> dict:
        out = {"effect": self.effect,
               "parameters": {k: v.to_json() for k, v in self.parameters.items()},
               "explained_fraction": float(self.explained_fraction),
               "unique_fraction": float(self.unique_fraction),
               "selection_gain": float(self.selection_gain),
               "folds_improved": int(self.folds_improved), "p_value": float(self.p_value),
               "n_params": int(self.n_params)}
        if self.effect_object is not None:
            out["effect_config"] = self.effect_object.as_config()
        if self.model_effect is not None:
            out["model_effect"] = self.model_effect.as_config()
        return out


@dataclass(frozen=True)
class Unexplained:
    """A part of the residual that the significance rule finds but no family explains.

    candidate: the family whose columns carry it; reason: why that family may not name it (its
    law fails a check the data can make); fraction: the held-out MSE drop its columns would give,
    over the held-out MSE of the model's own residual."""

    candidate: str
    reason: str
    fraction: float

    def __str__(self) -> str:
        return f"unexplained: {100 * self.fraction:.1f} % of the residual has the signature of " \
               f"{self.candidate}, which does not explain it ({self.reason})"

    def __repr__(self) -> str:
        return f"Unexplained({self.candidate!r}, fraction={self.fraction:.3g})"

    def to_json(self) -> dict:
        return {"candidate": self.candidate, "reason": self.reason,
                "fraction": float(self.fraction)}
