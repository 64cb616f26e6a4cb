"""``clm-sim export-ff``: a saved feedforward to C or ONNX for a real-time target.

Reads any feedforward the product saves: a run's ``params/lip.json``, a PGNN's
``params/<row>_seed<k>.pt`` (with its ``.json``), ``clm-sim identify``'s ``lip.json`` and a
diagnosis's ``diagnosis.json`` (its extended model as a LIP with effects). The sample time comes
from the file where it carries one, else from the run's ``config.resolved.yaml`` beside
``params/``, else from ``--ts``; a ``--ts`` that contradicts the file is refused. The output
folder appears whole or not at all and holds ``export.json`` (what was exported, from what).
"""

from __future__ import annotations

import json
import math
import pickle
from pathlib import Path

import yaml

from clm_sim.errors import UserError
from clm_sim.features import FeatureMap
from clm_sim.modelfile import mapping, read_json, sample_time
from clm_sim.outdir import atomic_folder
from clm_sim.record import RECORD_SUFFIXES
from clm_sim.schema import build_effect
from controllers.export import c_source
from controllers.export.options import DEFAULT_COUNT_M, DEFAULT_PREFIX, ExportOptions, safe_text
from controllers.export.window import DEFAULT_TOL, WindowFeedforward, from_lip, from_pgnn
from controllers.lip import LIPFeedforward

TARGETS = ("c", "onnx")
ONNX_FORMS = ("window", "mlp")
# The largest --filter-tail: a tenth of a per cent of the filter's weight left out is already a
# different filter (docs/export.md has the error it costs).
MAX_FILTER_TAIL = 1e-3
KNOWN = ("a run's params/lip.json or params/<row>_seed<k>.pt, identify's lip.json or a "
         "diagnosis.json")


def _run_config(path: Path) -> dict:
    """The resolved config of the run a ``params/`` file belongs to (``{}`` if none)."""
    cfg = path.resolve().parent.parent / "config.resolved.yaml"
    if path.resolve().parent.name != "params" or not cfg.is_file():  # only a run's own params/
        return {}
    try:
        data = yaml.safe_load(cfg.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise UserError(f"{cfg}: cannot read the run's config ({exc})") from None
    return data if isinstance(data, dict) else {}


def _sample_time(path: Path, stored, option: float | None) -> float:
    if option is not None and not (math.isfinite(option) and option > 0):  # NaN contradicts none
        raise UserError(f"ts: expected a sample time in s (a finite number > 0), got {option!r}")
    ts = stored if stored is not None else _run_config(path).get("ts")
    if ts is not None and option is not None and abs(float(ts) - option) > 1e-12 * float(ts):
        raise UserError(f"{path}: the model was identified at ts = {float(ts):g} s; "
                        f"--ts {option:g} contradicts it")
    ts = option if ts is None else ts
    if ts is None:
        raise UserError(f"{path}: the file carries no sample time; pass --ts (s)")
    try:
        ts = sample_time(ts, "sample time")  # a finite, plausible number (not true, 1e-300)
    except UserError as exc:
        raise UserError(f"{path}: {exc}") from None
    # A rate from time stamps (a diagnosis's record) reads 9.999999999999999e-05 for 1e-4: kept
    # to 12 significant digits, far below any clock's accuracy.
    return float(f"{float(ts):.12g}")


def _read_json(path: Path) -> dict:
    """Strict JSON, checked as every model file (:mod:`clm_sim.modelfile`)."""
    return read_json(path, f"clm-sim feedforward ({KNOWN})")


def _effects(items) -> tuple:
    if not isinstance(items, list):
        raise UserError("effects: expected a list")
    return tuple(build_effect(e, f"effects[{i}]") for i, e in enumerate(items))


def _agree_with_coefficients(data: dict) -> None:
    """A LIP file states its parameters twice (top level: what is loaded; ``coefficients``: the
    fit's): an edit of one alone leaves a file whose export is not the identified model."""
    coefficients = data.get("coefficients")
    if not isinstance(coefficients, dict):
        return
    offsets = [e.get("force") for e in data.get("effects") or []
               if isinstance(e, dict) and e.get("type") == "force_offset"]
    for key, value in coefficients.items():
        # the offset's loaded value is the force_offset effect's force (identify --offset)
        top = (offsets[0] if len(offsets) == 1 else None) if key == "offset" else data.get(key)
        numbers = all(isinstance(x, (int, float)) and not isinstance(x, bool)
                      for x in (value, top))  # a true/false is the type check's to refuse
        if numbers and not math.isclose(value, top, rel_tol=1e-12, abs_tol=0.0):
            loaded = ("the force_offset effect's force" if key == "offset"
                      else f"the parameter {key!r}")
            raise UserError(f"coefficients.{key}: {value!r}, but {loaded} is {top!r}; which "
                            f"one was identified?")


def _physical_mass(wf: WindowFeedforward) -> None:
    """A LIP-form feedforward (no network) with a mass <= 0 pushes the machine against every
    acceleration it is asked for: not exported. (A PGNN's physical part is only part of its
    force, its network the rest.)"""
    mass = wf.theta.get("mass")
    if wf.network is None and not (isinstance(mass, (int, float)) and math.isfinite(mass)
                                   and mass > 0):
        raise UserError(f"mass {mass:g} kg: a feedforward needs a mass > 0 (it would push "
                        f"against every acceleration); identify it again from a record that "
                        f"determines it")


def _lip(path: Path, data: dict, ts: float | None) -> WindowFeedforward:
    _agree_with_coefficients(data)
    run_features = _run_config(path).get("features") or {}
    try:
        features = mapping(data.get("features"), "features") or run_features
        features = FeatureMap(**{k: features[k] for k in ("position_lowpass_hz",)
                                 if k in features})
        lip = LIPFeedforward.fitted(theta=data, effects=_effects(data.get("effects") or []),
                                    features=features)
    except (UserError, TypeError, ValueError) as exc:
        raise UserError(f"{path}: {exc}") from None
    return from_lip(lip, _sample_time(path, data.get("ts"), ts), path.name)


def _diagnosis(path: Path, data: dict, ts: float | None) -> WindowFeedforward:
    model = data["extended_model"]
    try:
        stored = mapping(data.get("record"), "record").get("sample_time_s")
    except UserError as exc:
        raise UserError(f"{path}: {exc}") from None
    try:
        lip = LIPFeedforward.fitted(theta=model, effects=_effects(model.get("effects") or []))
    except (UserError, TypeError, ValueError) as exc:
        raise UserError(f"{path}: extended_model: {exc}") from None
    return from_lip(lip, _sample_time(path, stored, ts), f"{path.name} (extended model)")


def _pgnn(path: Path, ts: float | None, filter_tail: float) -> WindowFeedforward:
    from controllers.pgnn import PGNNFeedforward  # torch only for a PGNN

    stem = path.with_suffix("")
    for need in (stem.with_suffix(".pt"), stem.with_suffix(".json")):
        if not need.is_file():
            raise UserError(f"{path}: a PGNN needs {need.name} beside it")
    try:
        model = PGNNFeedforward.load(stem)
    except pickle.UnpicklingError as exc:  # a foreign .pt (load names only the errors it expects)
        raise UserError(f"{path}: cannot read PGNN model ({str(exc).splitlines()[0]})") from None
    data = _read_json(stem.with_suffix(".json"))
    return from_pgnn(model, _sample_time(path, data.get("ts"), ts), stem.with_suffix(".pt").name,
                     tol=filter_tail)


def load_feedforward(path, ts: float | None = None,
                     filter_tail: float = DEFAULT_TOL) -> WindowFeedforward:
    """The window form of the feedforward saved at ``path`` (see the module docstring); a
    PGNN's feature filter cut where its discarded tail is below ``filter_tail`` of its sum."""
    path = Path(path)
    try:
        wf = _load(path, ts, filter_tail)
        _physical_mass(wf)
        return wf
    except UserError as exc:  # every message names the file
        message = str(exc)
        raise UserError(message if str(path) in message else f"{path}: {message}") from None


def _load(path: Path, ts: float | None, filter_tail: float) -> WindowFeedforward:
    if not path.is_file():
        raise UserError(f"{path}: no such model file")
    if path.suffix == ".pt":
        return _pgnn(path, ts, filter_tail)
    if path.suffix.lower() in RECORD_SUFFIXES:
        raise UserError(f"{path}: a record ({path.suffix.lower()}), not a clm-sim feedforward "
                        f"({KNOWN})")
    if path.suffix != ".json":
        raise UserError(f"{path}: not a clm-sim feedforward ({KNOWN})")
    data = _read_json(path)
    if data.get("kind") == "pgnn":
        return _pgnn(path, ts, filter_tail)
    if data.get("kind") == "lip":
        return _lip(path, data, ts)
    if isinstance(data.get("extended_model"), dict):
        return _diagnosis(path, data, ts)
    raise UserError(f"{path}: not a clm-sim feedforward ({KNOWN})")


def float_build(wf: WindowFeedforward, count_m: float) -> dict:
    """What export.json says of the C float build (``-DCLM_FF_FLOAT``): its input and the error
    docs/export.md measured for it."""
    return {"reference": f"int64 counts of {count_m!r} m", "count_m": count_m,
            "error": "vs the double build on the same counts, of the peak force on r2 (n_l = 16 "
                     "run): LIP 1e-7; PGNN 4e-7 (clm_ff), 3e-6 (stream); see docs/export.md"}


def export(model_path, to: str, out, *, ts: float | None = None,
           filter_tail: float | None = None, prefix: str | None = None,
           max_force: float | None = None, max_slew: float | None = None,
           count_m: float | None = None, onnx_form: str = "window") -> list[Path]:
    """Export the feedforward at ``model_path`` as ``to`` (``c`` or ``onnx``) into folder
    ``out`` (replaced as a whole; an earlier export there is replaced). ``filter_tail``: where a
    PGNN's feature filter is cut (the discarded tail's share of its sum; default 1e-15, i.e.
    rounding): a larger value shortens the window and the look-ahead and costs accuracy
    (docs/export.md). ``prefix``: the names of every public symbol and macro and of the files
    (default ``clm_ff``); ``max_force`` (N) and ``max_slew`` (N/s): the output limits the C
    starts with (``None``: none); ``count_m`` (m): one count of the C float build's fixed-point
    reference (default 1e-12); ``onnx_form``: ``window`` (the reference window in, as the C) or
    ``mlp`` (the filtered features in, MatMul/Add/Tanh only). Returns the files."""
    if to not in TARGETS:
        raise UserError(f"--to: expected one of {', '.join(TARGETS)}, got {to!r}")
    if filter_tail is None:
        filter_tail = DEFAULT_TOL
    if not (isinstance(filter_tail, (int, float)) and 0 < filter_tail <= MAX_FILTER_TAIL):
        raise UserError(f"--filter-tail: expected a number in (0, {MAX_FILTER_TAIL:g}], got "
                        f"{filter_tail!r}")
    if onnx_form not in ONNX_FORMS:
        raise UserError(f"--onnx-form: expected one of {', '.join(ONNX_FORMS)}, got "
                        f"{onnx_form!r}")
    if onnx_form != "window" and to != "onnx":
        raise UserError("--onnx-form: only with --to onnx")
    if count_m is not None and to != "c":
        raise UserError("--count-m: the count of the C float build; only with --to c")
    limits = {"max_force": max_force, "max_slew": max_slew,
              "count_m": DEFAULT_COUNT_M if count_m is None else count_m}
    options = ExportOptions(prefix=DEFAULT_PREFIX if prefix is None else prefix,
                            **limits)  # checked before reading
    if to == "onnx" and (max_force is not None or max_slew is not None):
        raise UserError("--max-force/--max-slew: the limits are part of the C export only (an "
                        "ONNX runtime applies its own)")
    writer = c_source.write
    if to == "onnx":
        try:
            from controllers.export import onnx_graph
            import onnx  # noqa: F401
        except ImportError:
            raise UserError("--to onnx needs the export extra: pip install 'clm-sim[export]'") \
                from None
        writer = onnx_graph.mlp_write if onnx_form == "mlp" else onnx_graph.write
    wf = load_feedforward(model_path, ts, float(filter_tail))
    options = ExportOptions.traced(model_path, prefix=options.prefix, **limits)
    out = Path(out)
    try:
        # the model (and the .pt or .json beside it) would be deleted with an earlier export
        with atomic_folder(out, what="an exported feedforward",
                           subdirs=(), inputs=(model_path,)) as tmp:
            names = [p.name for p in writer(wf, tmp, options)]
            (tmp / "export.json").write_text(json.dumps({
                "model": options.model_name, "kind": wf.kind, "to": to, "ts": wf.ts,
                "lag": wf.lag, "lead": wf.lead,
                "filter_tail": wf.filter.get("tol") if wf.filter.get("cutoff_hz") else None,
                "prefix": options.prefix, "max_force": max_force, "max_slew": max_slew,
                **({"float_build": float_build(wf, options.count_m)} if to == "c" else
                   {"onnx_form": onnx_form}),
                "trace": options.trace(), "files": names,
                "description": safe_text(wf.describe())},
                indent=1))
    except OSError as exc:
        raise UserError(f"{out}: cannot write the export ({exc.strerror or exc})") from None
    return [out / n for n in names]
