"""``clm-sim diagnose`` as a library call: the record guards, the warnings, the diagnosis, and
errors that name the file they are about."""

from __future__ import annotations

from clm_sim.errors import UserError
from clm_sim.features import FeatureMap
from clm_sim.outdir import check_output_folder
from controllers.lip import LIPFeedforward
from experiments.diagnosis.diagnose import Diagnosis, diagnose
from experiments.diagnosis.report import write
from experiments.diagnosis.residual import DiagnosisSettings
from experiments.model_files import SimulationModel, load_model
from experiments.records.guards import fit_warnings, refuse_unidentifiable
from experiments.records.suspicions import record_warnings


def model_for(path, ts: float) -> SimulationModel:
    """The simulation's model: the default CLM without a file, else ``load_model``'s reading."""
    return SimulationModel() if path is None else load_model(path, ts)


def warnings_for(record, model, settings: DiagnosisSettings, source) -> list[str]:
    """:func:`experiments.records.suspicions.record_warnings` of a record against a diagnosis model,
    and :func:`experiments.records.guards.fit_warnings` of its LIP at the diagnosis's band."""
    try:
        lip = LIPFeedforward().fit(y=record.y, u=record.u, ts=record.ts)
    except UserError:  # the diagnosis says why the record cannot be fitted
        lip = None
    plant = getattr(model, "plant", None)
    out = record_warnings(record, lip, model_mass=getattr(plant, "mass", None))
    band = FeatureMap(regression_lowpass_hz=min(settings.regression_lowpass_hz, 0.2 / record.ts))
    try:
        fitted = LIPFeedforward(features=band).fit(y=record.y, u=record.u, ts=record.ts)
    except UserError:
        return out
    def refit(y, cutoff):
        try:
            return LIPFeedforward(features=FeatureMap(regression_lowpass_hz=cutoff)).fit(
                y=y, u=record.u, ts=record.ts).theta_["mass"]
        except UserError:
            return float("nan")

    return out + fit_warnings(record, band, fitted.theta_, fitted.std_,
                              option="--regression-lowpass-hz", refit=refit)


def diagnose_record(record, *, source, model_path=None, validation=None, validation_source=None,
                    regression_lowpass_hz: float | None = None,
                    warn=lambda lines: None) -> Diagnosis:
    """The diagnosis of ``record`` (read from ``source``) against the model at ``model_path``
    (default: the default CLM); ``warn`` receives the warning lines before the work. Refuses in
    one line a record that identifies nothing; every error names its file."""
    refuse_unidentifiable(record, source)
    model = model_for(model_path, record.ts)
    settings = DiagnosisSettings() if regression_lowpass_hz is None else \
        DiagnosisSettings(regression_lowpass_hz=regression_lowpass_hz)
    warn(warnings_for(record, model, settings, source))
    try:
        return diagnose(record, model, validation=validation, settings=settings)
    except UserError as exc:  # name the file the error is about
        text = str(exc)
        named = text.startswith(str(source)) or (
            validation_source and text.startswith(str(validation_source)))
        raise UserError(text if named else f"{source}: {text}") from None


def diagnose_files(data, *, out, read, model_path=None, validate=None,
                   regression_lowpass_hz: float | None = None,
                   warn=lambda lines: None) -> Diagnosis:
    """``clm-sim diagnose``: the record file ``data`` (and ``validate``) read by ``read``,
    diagnosed (:func:`diagnose_record`) and written into ``out`` (checked before the work)."""
    check_output_folder(out, what="a diagnosis",
                        inputs=(data, model_path, validate))
    record = read(data)
    validation = read(validate) if validate else None
    result = diagnose_record(record, source=data, model_path=model_path, validation=validation,
                             validation_source=validate,
                             regression_lowpass_hz=regression_lowpass_hz, warn=warn)
    write(result, out)
    return result
