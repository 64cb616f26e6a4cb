"""The typed parts of a :class:`~experiments.diagnosis.diagnose.Diagnosis` besides its findings:
the out-of-sample gain (and its part on a validation record with its encoder origin registered),
the signals the report draws, and what the diagnosis states about the record and its rule.

Each type writes the keys of ``diagnosis.json`` through its own ``to_json``: the field names
are the file's keys, in the file's order, and a field that is None (not measured on this record,
e.g. no controller given) is left out of the file.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from experiments.diagnosis.residual import DiagnosisSettings, Residual


def _present(obj) -> dict:
    """The fields of ``obj`` that are not None, in declaration order; tuples as lists."""
    out = {}
    for f in fields(obj):
        value = getattr(obj, f.name)
        if value is None:
            continue
        out[f.name] = list(value) if isinstance(value, tuple) else value
    return out


@dataclass(frozen=True)
class OriginGain:
    """The gain on a separate validation record with its encoder origin registered: ``shift_m``
    (m) found on the record's first part (``registered_on``), modulo ``period_m`` (m); force
    residual RMS (N) on the other ``samples`` of the model, of the extended model at the fixed
    origin and registered; with a controller, the re-simulated tracking mismatch RMS (m) too."""

    shift_m: float
    period_m: float
    registered_on: str
    samples: int
    residual_rms_before: float
    residual_rms_after_fixed_origin: float
    residual_rms_after: float
    residual_rms_reduction: float
    resim_mismatch_rms_before: float | None = None
    resim_mismatch_rms_after: float | None = None
    resim_mismatch_rms_after_fixed_origin: float | None = None

    def to_json(self) -> dict:
        return _present(self)


@dataclass(frozen=True)
class Gain:
    """Out of sample, model against extended model: force residual RMS (N) on the validation
    data, the encoder's quantization floor (N); a LIP re-identified without and with the found
    effects (``lip_error`` where it cannot take them); the open-loop simulation's position RMSE
    (m; ``simulation_error`` where it fails); the origin-registered gain (``origin_error`` where
    it fails); with a controller, the measured tracking RMS and the re-simulated mismatch (m)."""

    residual_rms_before: float
    residual_rms_after: float
    validation_samples: int
    fitted_validation_samples: int
    residual_rms_reduction: float
    quantization_floor_n: float
    lip_effects: tuple[str, ...] = ()
    lip_residual_rms_before: float | None = None
    lip_residual_rms_after: float | None = None
    lip_error: str | None = None
    simulation_rmse_before: float | None = None
    simulation_rmse_after: float | None = None
    simulation_init_samples: int | None = None
    simulation_error: str | None = None
    origin_error: str | None = None
    origin: OriginGain | None = None
    resimulation_error: str | None = None
    tracking_rms_measured: float | None = None
    resim_mismatch_rms_before: float | None = None
    resim_mismatch_rms_after: float | None = None

    def to_json(self) -> dict:
        out = _present(self)
        if self.origin is not None:
            out["origin"] = self.origin.to_json()
        return out


@dataclass(frozen=True, eq=False)
class GainSignals:
    """What the report draws of the gain: the residuals of the model and of the extended model
    on the validation data; the origin scan ``(delta, shifts, rms)`` (m, m, N) where one was
    registered; with a controller, the time (s) and the measured and re-simulated tracking
    errors (m) on the validation data."""

    val_before: Residual
    val_after: Residual
    origin_scan: tuple[float, np.ndarray, np.ndarray] | None = None
    t: np.ndarray | None = None
    e_measured: np.ndarray | None = None
    e_before: np.ndarray | None = None
    e_after: np.ndarray | None = None


@dataclass(frozen=True)
class RecordInfo:
    """The estimation record as the diagnosis read it: its source, length, sample time (s),
    encoder step (m), the speed floor below which the direction of motion is unknown (m/s), the
    parallel low-pass (Hz), the quantization floor (N), the fitted and effective sample counts and
    the model's residual RMS (N)."""

    source: str
    samples: int
    sample_time_s: float
    encoder_quantum_m: float
    speed_floor_m_s: float
    regression_lowpass_hz: float
    quantization_floor_n: float
    fitted_samples: int
    effective_samples: float
    residual_rms_n: float

    def to_json(self) -> dict:
        return _present(self)


@dataclass(frozen=True)
class SignificanceRule:
    """The rule a candidate passed (:class:`DiagnosisSettings`), as the report states it."""

    cv: str
    min_gain: float
    min_explained: float
    min_folds: int
    min_force_fraction: float
    p_value: float
    max_findings: int

    @classmethod
    def of(cls, settings: DiagnosisSettings) -> SignificanceRule:
        return cls(f"blocked {settings.folds}-fold cross-validation, contiguous blocks",
                   settings.min_gain, settings.min_explained, settings.min_folds,
                   settings.min_force_fraction, settings.p_value, settings.max_findings)

    def to_json(self) -> dict:
        return _present(self)


@dataclass(frozen=True)
class FeedforwardGain:
    """On an emulated machine: the LIP feedforward's tracking MAE (m) per replay reference,
    ``{reference: {"before": ..., "after": ...}}``, before and after adding the found effects
    (``lip_effects``, as configs), and the diagnosis's force residual RMS (N)."""

    lip_mae_m: dict
    lip_effects: tuple[dict, ...]
    residual_rms_before: float
    residual_rms_after: float

    def to_json(self) -> dict:
        return _present(self)


@dataclass(frozen=True)
class DiagnosisInfo:
    """What the diagnosis states besides its findings and gain: the ``record``, which data
    validated (``validation``), the ``significance_rule``, and on an emulated machine the
    ``feedforward_gain``."""

    record: RecordInfo
    validation: str
    significance_rule: SignificanceRule
    feedforward_gain: FeedforwardGain | None = None

    def to_json(self) -> dict:
        out = {"record": self.record.to_json(), "validation": self.validation,
               "significance_rule": self.significance_rule.to_json()}
        if self.feedforward_gain is not None:
            out["feedforward_gain"] = self.feedforward_gain.to_json()
        return out
