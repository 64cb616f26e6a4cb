"""The diagnosis end to end: residual -> named causes -> extended model -> out-of-sample gain."""

from __future__ import annotations

from dataclasses import dataclass

from experiments.diagnosis.extend import extended_plant, gains, joint_fit
from experiments.diagnosis.finding import Finding, Unexplained
from experiments.diagnosis.outcome import (DiagnosisInfo, Gain, GainSignals, RecordInfo,
                                           SignificanceRule)
from experiments.diagnosis.residual import DiagnosisSettings, Residual, source_of
from experiments.diagnosis.search import forward_select
from experiments.model_files import SimulationModel
from experiments.records.guards import refuse_other_rate
from clm_sim.effects.base import Effect
from clm_sim.errors import UserError, check_ts
from clm_sim.numerics import single_threaded
from clm_sim.plant import Plant
from clm_sim.run import Run


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
    r"""Show what ``model`` gets wrong on a measured ``record``, name the physical cause,
    extend the model and measure the gain out of sample.

    The force residual (measured ``u`` minus the model's inverse dynamics) is fitted with the
    candidate effects of the library; an effect is named only when it passes the significance
    and parsimony rules and its family's law holds on the data (docs/diagnosis.md). The causes
    are selected on ``record`` (or on its first ``1 - holdout_fraction`` when no
    ``validation`` record is given) and the gain is measured on the validation data. Runs
    with one BLAS thread, so the findings do not depend on the machine's cores.

    Parameters
    ----------
    record : Run
        The measured record (``t, r, y, u``), e.g. from :func:`load_record`.
    model : SimulationModel
        The simulation's model, from :func:`load_model`.
    validation : Run, optional
        A second record to measure the gain on (default: the final part of ``record``).
    settings : DiagnosisSettings
        The significance rule and the filter.

    Returns
    -------
    Diagnosis
        ``findings`` (ranked; each with its ``effect``, parameters with standard errors and
        ``values()``), what stays ``unexplained``, the out-of-sample ``gain``, the
        ``extended`` plant and the found ``effects``; ``summary()`` is what
        ``clm-sim diagnose`` prints.

    Raises
    ------
    UserError
        A record sampled at another rate than the model's controller, a record too short to
        hold out a validation part, too little excitation to identify anything.

    Examples
    --------
    >>> from pathlib import Path
    >>> from clm_sim import ExperimentConfig, Plant, PointToPoint, Testbed, Training
    >>> from clm_sim.effects import Cogging
    >>> moves = PointToPoint(points_m=(0.0,) + (0.02, -0.02) * 4 + (0.0,), dwell_s=0.05)
    >>> machine = Plant(effects=(Cogging(amplitude=3.0, period=0.008),))  # hidden from the model
    >>> config = ExperimentConfig(plant=Plant(effects=()), truth=machine, references={"r": moves},
    ...                           training=Training(reference="r", repeats=1), replay=("r",))
    >>> record = Testbed(config).training_run(seed=1)      # 7 s measured on the machine
    >>> _ = Path("model.yaml").write_text(
    ...     "ts: 1.0e-4\nplant: {effects: []}\ncontroller: {crossover_hz: 30.0}\n")
    >>> from clm_sim import diagnose, load_model
    >>> result = diagnose(record, load_model("model.yaml"))
    >>> [f.effect for f in result.findings], [e.type for e in result.extended.effects]
    (['cogging'], ['cogging'])
    >>> found = result.findings[0].values()
    >>> round(found["period"], 4), round(found["amplitude"], 1)          # m, N
    (0.008, 3.0)
    >>> result.gain.residual_rms_after < 0.1 * result.gain.residual_rms_before  # held out, N
    True
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
