"""The diagnosis end to end: residual -> named causes -> extended model -> out-of-sample gain."""

from __future__ import annotations

from dataclasses import dataclass

from experiments.diagnosis.extend import extended_plant, gains, joint_fit
from experiments.diagnosis.finding import Finding, Unexplained
from experiments.diagnosis.model import SimulationModel
from experiments.diagnosis.outcome import (DiagnosisInfo, Gain, GainSignals, RecordInfo,
                                           SignificanceRule)
from experiments.diagnosis.residual import DiagnosisSettings, Residual, source_of
from experiments.diagnosis.search import forward_select
from experiments.record_guards import refuse_other_rate
from clm_sim.effects import Effect
from clm_sim.errors import UserError, check_ts
from clm_sim.numerics import single_threaded
from clm_sim.plant import Plant
from clm_sim.record import Run


@dataclass
class Diagnosis:
    """Result of :func:`diagnose`: ``findings`` (ranked :class:`Finding`), what stays
    ``unexplained``, ``gain`` (out of sample), the ``extended`` plant and found ``effects``, and
    the residuals the report draws. :meth:`summary` is the one rendering every front end prints."""

    findings: tuple[Finding, ...]
    gain: Gain
    model: SimulationModel
    extended: Plant
    effects: tuple[Effect, ...]
    correction: dict
    estimation: Residual
    signals: GainSignals
    info: DiagnosisInfo
    unexplained: tuple[Unexplained, ...] = ()

    def __repr__(self) -> str:
        return f"Diagnosis(findings={list(self.findings)!r}, " \
               f"unexplained={list(self.unexplained)!r})"

    def summary(self) -> str:
        """The findings, what stays unexplained and the out-of-sample gain, one per line."""
        lines = [f"{k}. {f}" for k, f in enumerate(self.findings, 1)]
        if not self.findings and not self.unexplained:
            lines.append("no significant discrepancy: the model explains the record")
        elif not self.findings:
            lines.append("no cause named")
        lines += [str(u) for u in self.unexplained]
        g = self.gain
        if g.simulation_rmse_before is not None:
            lines.append(f"open-loop simulation of the validation data from its input (initial "
                         f"state from its first {g.simulation_init_samples} positions): "
                         f"position RMSE {g.simulation_rmse_before * 1e3:.4g} mm -> "
                         f"{g.simulation_rmse_after * 1e3:.4g} mm")
        lines.append(f"out-of-sample force residual RMS {g.residual_rms_before:.4g} N -> "
                     f"{g.residual_rms_after:.4g} N "
                     f"({-100 * g.residual_rms_reduction:+.1f} %; the encoder's "
                     f"quantization floor is {g.quantization_floor_n:.2g} N)")
        if g.origin is not None:
            o = g.origin
            lines.append(f"with the validation record's encoder origin registered on the "
                         f"{o.registered_on}: shift {o.shift_m * 1e3:+.4g} mm modulo "
                         f"{o.period_m * 1e3:.4g} mm; {o.residual_rms_before:.4g} N -> "
                         f"{o.residual_rms_after:.4g} N on the rest "
                         f"({-100 * o.residual_rms_reduction:+.1f} %; fixed origin "
                         f"{o.residual_rms_after_fixed_origin:.4g} N)")
        return "\n".join(lines)

    def to_json(self) -> dict:
        plant = self.extended
        return {
            "findings": [f.to_json() for f in self.findings],
            "unexplained": [u.to_json() for u in self.unexplained],
            "gain": self.gain.to_json(),
            "model": {"name": self.model.name, **{k: float(getattr(self.model.plant, k)) for k in
                                                  ("mass", "viscous", "coulomb", "stiffness")},
                      "effects": [e.as_config() for e in self.model.plant.effects]},
            "extended_model": {**{k: float(getattr(plant, k)) for k in
                                  ("mass", "viscous", "coulomb", "stiffness")},
                               "effects": [e.as_config() for e in plant.effects]},
            **self.info.to_json(),
        }


def diagnose(record: Run, model: SimulationModel, *, validation: Run | None = None,
             settings: DiagnosisSettings = DiagnosisSettings()) -> Diagnosis:
    """Diagnose ``model`` against a measured ``record``.

    The causes are selected on ``record`` (or on its first ``1 - holdout_fraction`` when no
    ``validation`` record is given) and the gain is measured on the validation data.

    Runs with one BLAS thread (:func:`clm_sim.numerics.single_threaded`): OpenBLAS splits some
    sums over its threads, so with the machine's default the last digits of the findings
    depended on its number of cores.
    """
    with single_threaded():
        return _diagnose(record, model, validation=validation, settings=settings)


def _diagnose(record: Run, model: SimulationModel, *, validation: Run | None,
              settings: DiagnosisSettings) -> Diagnosis:
    if model.controller is not None:  # a controller runs at its own rate only
        check_ts(model.controller.ts, record.ts, f"{source_of(record)}: the model's controller "
                 f"({model.name})")
    offset = None
    est, val = record, validation
    if validation is None:
        offset = int(round(len(record) * (1 - settings.holdout_fraction)))
        est, val = record.slice(0, offset), record.slice(offset)
        if len(val) < 200:
            raise UserError(f"{source_of(record)}: record too short to hold out a validation "
                            f"part ({len(record)} samples); give --validate")
    else:
        refuse_other_rate(validation, record, source_of(validation))
    res = Residual(est, model.plant, settings)
    selection = forward_select(res)
    steps = list(selection.steps)
    findings, correction, effects = joint_fit(res, steps)
    if any(f.effect == "parameter_mismatch" and not f.parameters for f in findings):
        # Significant at its step, but in the final joint fit no parameter passes the reporting
        # rule (later terms took its share): nothing to name, so it is not part of the model.
        steps = [s for s in steps if s.term.effect != "parameter_mismatch"]
        findings, correction, effects = joint_fit(res, steps)
    extended = extended_plant(model.plant, correction, effects)
    gain, signals = gains(est, val, settings, model.plant, extended, effects, model.controller,
                          val_offset=offset, full=record)
    info = DiagnosisInfo(
        record=RecordInfo(source=source_of(record), samples=len(record), sample_time_s=record.ts,
                          encoder_quantum_m=res.quantum, speed_floor_m_s=res.v_floor,
                          regression_lowpass_hz=res.cutoff,
                          quantization_floor_n=res.quantization_floor(),
                          fitted_samples=int(len(res.idx)), effective_samples=res.n_eff,
                          residual_rms_n=res.rms()),
        validation=source_of(validation) if validation is not None else
        f"held-out final {100 * settings.holdout_fraction:.0f} % of the record",
        significance_rule=SignificanceRule.of(settings))
    return Diagnosis(tuple(findings), gain, model, extended, effects, correction, res, signals,
                     info, selection.unexplained)
