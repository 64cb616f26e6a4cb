"""``clm-sim identify``: a LIP from a record, by the product's defaults or a published protocol.

    record (+ validation record) -> IDIM-LS fit (controllers.idim) -> lip.json, printed summary,
    cross-test force error on the validation record (the same processing)
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from clm_sim.errors import UserError
from clm_sim.outdir import atomic_folder
from clm_sim.plant import THETA_UNITS
from clm_sim.run import Run
from controllers.idim import CrossTest, IDIMFit, IDIMProtocol, cross_test, fit

WHAT = "an identified model"  # the kind of result folder identify writes (clm_sim.outdir)

UNITS = {**THETA_UNITS, "offset": "N"}


@dataclass(frozen=True)
class Identified:
    """What ``identify`` found: the ``fit``, the record it came from, the cross-test on the
    validation record (None without one) and the data warnings (one line each)."""

    fit: IDIMFit
    run: Run
    source: str
    cross: CrossTest | None = None
    validation: str | None = None
    warnings: tuple[str, ...] = ()

    def summary(self) -> str:
        """The coefficients, the residual and the cross-test, one per line."""
        f = self.fit
        lines = [f"{name:10s} {value:12.6g} {UNITS[name]:6s} (std {f.std[name]:.2g})"
                 for name, value in f.coefficients.items()]
        if not f.protocol.stiffness:
            lines.append(f"{'stiffness':10s} {0.0:12.6g} {UNITS['stiffness']:6s} (fixed)")
        lines.append(f"residual rms {f.residual_rms_n:.4g} N, relative error "
                     f"{100 * f.relative_error:.3g} % over {f.samples} fitted samples "
                     f"({len(self.run)} at {1 / self.run.ts:g} Hz)")
        if self.cross is not None:
            lines.append(f"cross-test on {self.validation}: residual rms "
                         f"{self.cross.residual_rms_n:.4g} N, relative error "
                         f"{100 * self.cross.relative_error:.3g} % over {self.cross.samples} "
                         f"samples (the same processing)")
        return "\n".join(lines)


def identify(run: Run, protocol: IDIMProtocol, *, source: str,
             validation: Run | None = None, validation_source: str | None = None
             ) -> Identified:
    """Fit ``run`` by ``protocol``; cross-test on ``validation`` (same sample time) if given.
    Errors name ``source`` (or ``validation_source``)."""
    from experiments.records.guards import (fit_warnings, refuse_other_rate,
                                           refuse_unidentifiable)
    from experiments.records.suspicions import record_warnings

    refuse_unidentifiable(run, source)
    try:
        with np.errstate(invalid="ignore", divide="ignore"):  # non-finite: refused just below
            result = fit(y=run.y, u=run.u, ts=run.ts, protocol=protocol)
    except UserError as exc:  # name the file, and the option of a filter setting
        text = f"{source}: {exc}"
        for key in ("regression_lowpass_hz", "position_lowpass_hz"):
            if key in text:
                text += f" (--{key.replace('_', '-')})"
        raise UserError(text) from None
    values = {**result.coefficients, **result.std}
    values.update(residual=result.residual_rms_n, **{"relative error": result.relative_error})
    bad = [name for name, value in values.items() if not math.isfinite(value)]
    if bad:
        raise UserError(f"{source}: the fit gives non-finite parameters "
                        f"({', '.join(sorted(set(bad)))}); the record's values are too large, "
                        f"too small or degenerate for a least-squares fit (check how u and y are "
                        f"scaled)")
    cross = None
    if validation is not None:
        refuse_other_rate(validation, run, validation_source)
        try:
            cross = cross_test(result, y=validation.y, u=validation.u, ts=validation.ts)
        except UserError as exc:
            raise UserError(f"{validation_source}: {exc}") from None

    def refit(y, cutoff):  # the mass the same protocol gives on positions y, in band cutoff (Hz)
        try:
            band = replace(protocol, regression_lowpass_hz=cutoff)
            return fit(y=y, u=run.u, ts=run.ts, protocol=band).coefficients["mass"]
        except UserError:
            return float("nan")

    warnings = record_warnings(run, result.model) + fit_warnings(
        run, protocol.feature_map(), result.coefficients, result.std,
        option="--regression-lowpass-hz", refit=refit)
    return Identified(result, run, source, cross, validation_source, tuple(warnings))


def write(result: Identified, out: Path, extra: dict[str, str] | None = None) -> Path:
    """Write ``out/lip.json`` (the model, its source and the protocol) and the ``extra`` files
    (name -> text) into one result folder; returns the path of ``lip.json``."""
    info = {**result.fit.model.to_json(), "source": result.source,
            "identification": {**result.fit.protocol.as_dict(),
                               "relative_error": result.fit.relative_error,
                               "fitted_samples": result.fit.samples}}
    if result.cross is not None:
        info["cross_test"] = {"record": result.validation,
                              "relative_error": result.cross.relative_error,
                              "residual_rms_n": result.cross.residual_rms_n,
                              "samples": result.cross.samples}
    text = json.dumps(info, indent=1, allow_nan=False)
    with atomic_folder(out, what=WHAT, subdirs=()) as tmp:
        (tmp / "lip.json").write_text(text)
        for name, body in (extra or {}).items():
            (tmp / name).write_text(body)
    return out / "lip.json"


def protocol_from_options(args, *, source: str):
    """The :class:`IDIMProtocol` of ``identify``'s command-line options (``args``: the parsed
    namespace); a bad setting is a ``UserError`` naming ``source``."""
    cutoff = args.regression_lowpass_hz
    try:
        return IDIMProtocol(
            regression_lowpass_hz=250.0 if cutoff is None else (None if cutoff <= 0 else cutoff),
            position_lowpass_hz=args.position_lowpass_hz or None, filter_order=args.filter_order,
            zero_phase=not args.causal, differentiation=args.differentiation.replace("-", "_"),
            decimation=args.decimate, offset=args.offset, stiffness=not args.no_stiffness,
            edge_samples=args.edge_samples, force_at=args.force_at)
    except UserError as exc:
        raise UserError(f"{source}: {exc}") from None


SIMULATION_OPTIONS = ("model", "hold", "starts", "seed", "init_samples")


def simulation_fit(result: Identified, *, model=None, model_source: str | None = None,
                   hold: tuple[str, ...] = (), starts: int = 2, seed: int = 0,
                   init_samples: int = 20):
    """The force fit of ``result`` refined on the open-loop simulation error of its record
    (:func:`experiments.records.output_error.fit`): the structure is ``model``'s plant (a
    :class:`~clm_sim.plant.Plant`) or else the force fit's; the starts are the force fit, the
    model, and ``starts`` perturbations of the force fit (seeded by ``seed``); ``hold`` names
    parameters kept at the force fit's value (the model's where the force fit has none)."""
    from clm_sim.effects.position import ForceOffset
    from clm_sim.plant import Plant
    from experiments.records import output_error as oe
    source = result.source
    lip = result.fit.model
    if not 3 <= init_samples <= len(result.run) - 100:
        raise UserError(f"--init-samples: expected 3 to {len(result.run) - 100} (the record "
                        f"has {len(result.run)} samples, 100 at least are scored), got "
                        f"{init_samples}")
    if starts < 0:
        raise UserError(f"--starts: expected a number of perturbed starts >= 0, got {starts}")
    equation = Plant(**lip.theta_, effects=lip.effects_)
    structure = oe.merge_offsets(model if model is not None else equation)
    if model is not None and result.fit.protocol.offset and not any(
            isinstance(e, ForceOffset) for e in structure.effects):
        structure = replace(structure, effects=(*structure.effects, ForceOffset(0.0)))
    try:
        names = oe.structure_parameters(structure)
        theirs = set(oe.structure_parameters(oe.merge_offsets(equation)))
    except UserError as exc:
        raise UserError(f"{model_source or source}: {exc}") from None
    own = {k: oe.value(oe.merge_offsets(equation), k) for k in names if k in theirs}
    unknown = [k for k in hold if k not in names]
    if unknown:
        raise UserError(f"--hold: {', '.join(unknown)} is not a parameter of the structure "
                        f"(its parameters: {', '.join(names)})")
    held = {k: own.get(k, oe.value(structure, k)) for k in hold}
    if len(held) == len(names):
        raise UserError(f"--hold: every parameter of the structure held ({', '.join(names)}); "
                        f"nothing to fit")
    free = [k for k in names if k not in held]
    first = {k: v for k, v in own.items() if k in free}
    begin = [("force fit", first)]
    if model is not None:
        begin.append((f"model {model_source}", {k: oe.value(structure, k) for k in free}))
    rng = np.random.default_rng(seed)
    full = {k: first.get(k, oe.value(structure, k)) for k in free}
    begin += [(f"perturbed {i + 1}", oe.perturbed(full, rng)) for i in range(starts)]
    try:
        return oe.fit(structure, result.run, begin, hold=held, init_samples=init_samples)
    except UserError as exc:
        raise UserError(f"{source}: {exc}") from None


def simulation_files(fit, result: Identified) -> dict[str, str]:
    """``model.json`` (a model file of the simulation-error fit, its stops under
    ``identification``) and ``simulation_fit.json`` (every start), as name -> text."""
    from experiments.records import output_error as oe
    info = oe.model_file(fit.plant, result.run.ts, name=f"{Path(result.source).stem} "
                         f"(simulation error)", description=fit.verdict())
    record = {"source": result.source, **fit.to_json()}
    return {"model.json": json.dumps(info, indent=1, allow_nan=False),
            "simulation_fit.json": json.dumps(record, indent=1, allow_nan=False)}


def command(args, *, load) -> int:
    """``clm-sim identify`` on the parsed ``args``; ``load(path, args)`` reads a record."""
    from clm_sim.outdir import check_output_folder
    from experiments.records.suspicions import warn

    simulation = args.criterion == "simulation"
    given = [k for k in SIMULATION_OPTIONS if getattr(args, k) is not None]
    if given and not simulation:
        raise UserError(f"--{given[0].replace('_', '-')}: an option of --criterion simulation "
                        f"(the default criterion is the force fit alone)")
    out = Path(args.out) if args.out else Path("results") / "identify" / Path(args.data).stem
    # before the work: a result that cannot be written is not computed
    check_output_folder(out, what=WHAT, inputs=(args.data, args.validate))
    protocol = protocol_from_options(args, source=str(args.data))
    model = None
    if args.model:
        from experiments.model_files import load_model
        model = load_model(args.model).plant
    hold = tuple(k.strip() for k in (args.hold or "").split(",") if k.strip())
    validation = load(args.validate, args) if args.validate else None
    result = identify(load(args.data, args), protocol, source=str(args.data),
                      validation=validation, validation_source=args.validate)
    warn(args.data, list(result.warnings))
    print(result.summary())
    if simulation:
        fit = simulation_fit(result, model=model, model_source=args.model, hold=hold,
                             starts=2 if args.starts is None else args.starts,
                             seed=args.seed or 0,
                             init_samples=20 if args.init_samples is None else
                             args.init_samples)
        print(f"simulation error (open loop from the input, initial state from a parabola "
              f"through the first {fit.init_samples} positions):")
        print(fit.summary())
        write(result, out, simulation_files(fit, result))
        print(f"wrote {out / 'model.json'} (a model for clm-sim simulate and "
              f"clm-sim diagnose --model), {out / 'lip.json'} (the force fit) and "
              f"{out / 'simulation_fit.json'} (every start's stop)")
        return 0
    print(f"wrote {write(result, out)} (a model for clm-sim diagnose --model and "
          f"clm-sim simulate)")
    return 0
