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

import numpy as np
import yaml

from clm_sim.errors import UserError
from clm_sim.features import FeatureMap
from clm_sim.modelfile import mapping, read_json, sample_time
from clm_sim.outdir import atomic_folder
from clm_sim.records.files import RECORD_SUFFIXES
from clm_sim.schema import build_effect
from controllers.export import c_source, selftest
from controllers.export.envelope import ABSURD, Envelope
from controllers.export.options import (
    DEFAULT_COUNT_M,
    DEFAULT_PREFIX,
    LIMIT_KEYS,
    ExportOptions,
    safe_text,
)
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
    effects = data.get("effects") or []
    if not isinstance(effects, list):  # the loader refuses it in one line, naming the key
        return
    offsets = [e.get("force") for e in effects
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


def _record_envelope(record, source: str, ts: float, cutoff, order: int) -> Envelope:
    from clm_sim.records.read import load_record

    run = record if not isinstance(record, (str, Path)) else load_record(record)
    if abs(run.ts - ts) > 1e-6 * ts:
        raise UserError(f"{source}: sampled at {run.ts:g} s, the model at {ts:g} s; not the "
                        f"model's data")
    return Envelope.of_record(run.y, run.u, ts, safe_text(Path(source).name), cutoff, order)


def _filter_of(path: Path, wf: WindowFeedforward) -> tuple:
    """The regression filter (cut-off in Hz or None, order) the model's fit saw its data
    through."""
    if wf.network is not None:
        return (wf.filter.get("cutoff_hz") or None, wf.filter.get("order", 4))
    features = {}
    if path.suffix == ".json":
        try:
            data = _read_json(path)
            features = data.get("features") or _run_config(path).get("features") or {}
        except UserError:
            features = {}
    if not isinstance(features, dict):
        features = {}
    cutoff = features.get("regression_lowpass_hz", 250.0)
    order = features.get("lowpass_order", 4)
    return (cutoff if isinstance(cutoff, (int, float)) else None,
            order if isinstance(order, int) else 4)


def _data_candidates(path: Path) -> list[tuple[str, object]]:
    """Where the data a model file was fitted on is, as far as its files say: a run's
    runs/training.npz, a data: run's training record (config.resolved.yaml), identify's and a
    diagnosis's record (their ``source``). ``(name, loader)`` pairs, the loader a path or a
    callable giving a record."""
    out: list[tuple[str, object]] = []
    run = path.resolve().parent.parent
    if path.resolve().parent.name == "params":
        if (run / "runs" / "training.npz").is_file():
            out.append(("runs/training.npz", run / "runs" / "training.npz"))
        data = _run_config(path).get("data")
        if isinstance(data, dict) and isinstance(data.get("training"), str):
            from experiments.config import RecordData

            try:
                spec = RecordData(training=data["training"], columns=data.get("columns"),
                                  scale=data.get("scale"))
                out.append((data["training"], spec.load))
            except (TypeError, UserError):
                pass
    if path.suffix == ".json":
        try:
            info = _read_json(path)
        except UserError:
            return out
        source = info.get("source")
        record = info.get("record")
        if isinstance(record, dict):
            source = record.get("source")
        if isinstance(source, str) and Path(source).is_file():
            out.append((source, Path(source)))
    return out


def training_envelope(path, wf: WindowFeedforward, limits_from=None) -> Envelope | None:
    """The envelope of the data the model at ``path`` was fitted on: of ``limits_from`` (a
    record) where given, else of the first record its files name that can be read (``None``
    if there is none)."""
    path = Path(path)
    cutoff, order = _filter_of(path, wf)
    if limits_from is not None:
        if not Path(limits_from).is_file():
            raise UserError(f"--limits-from: no such record {limits_from}")
        return _record_envelope(Path(limits_from), str(limits_from), wf.ts, cutoff, order)
    for name, loader in _data_candidates(path):
        try:
            record = loader() if callable(loader) else loader
            return _record_envelope(record, name, wf.ts, cutoff, order)
        except UserError:
            continue
    return None


# The option that sets each limit.
_OPTION = {"max_force": "--max-force", "max_slew": "--max-slew", "r_min": "--position-range",
           "r_max": "--position-range", "v_max": "--max-velocity", "a_max": "--max-acceleration"}


def resolve_limits(path, wf: WindowFeedforward, given: dict, *, no_limits: bool = False,
                   limits_from=None) -> tuple[dict, str, Envelope | None]:
    """The C export's limits: each given option, else the training data's envelope widened by
    its margin (:mod:`controllers.export.envelope`). ``(limits, where they come from, the
    envelope or None)``; without data and without every limit given, a ``UserError``."""
    envelope = training_envelope(path, wf, limits_from)
    if no_limits:
        if any(v is not None for k, v in given.items() if k != "max_slew") or limits_from:
            raise UserError("--no-limits: contradicts the limits given with it")
        return dict.fromkeys(LIMIT_KEYS), "none (--no-limits)", envelope
    derived = envelope.limits() if envelope is not None else {}
    limits = {k: given.get(k) if given.get(k) is not None else derived.get(k)
              for k in LIMIT_KEYS}
    missing = [k for k in LIMIT_KEYS if k != "max_slew" and limits[k] is None]
    if missing:
        names = dict.fromkeys(_OPTION[k] for k in missing)
        raise UserError(f"{path}: the default limits come from the data the model was fitted "
                        f"on, and no readable record of it was found beside the model; give "
                        f"--limits-from RECORD, or {', '.join(names)}, or --no-limits")
    where = "the options" if envelope is None else envelope.describe()
    if envelope is not None and any(given.get(k) is not None for k in LIMIT_KEYS):
        where += " (some set by options)"
    return limits, where, envelope


def check_vectors(wf: WindowFeedforward, options: ExportOptions, envelope: Envelope | None,
                  c: bool) -> None:
    """Refuse a model whose known-answer forces are not finite, or absurd for its data (where it
    is known): more than ``ABSURD`` times the data's largest force on a motion inside its
    envelope (not the force limit: a limit below the model's forces is a user's choice); and a
    float-build count that leaves the vectors' motion without resolution or beyond the counts'
    range."""
    limits = options.limits()
    r, u = selftest.vectors(wf, limits)
    peak = float(np.max(np.abs(u)))
    if not np.all(np.isfinite(u)):
        raise UserError(f"{options.model_name}: the model's force on the known-answer motion "
                        f"is not finite (NaN or inf); not a usable model")
    if envelope is not None and peak > ABSURD * envelope.force_n:
        raise UserError(f"{options.model_name}: a force of {peak:.3g} N on a motion inside its "
                        f"envelope, more than {ABSURD:g} times its data's largest force "
                        f"({envelope.force_n:.4g} N); not a fit of that data (a parameter in the "
                        f"wrong unit?)")
    if c:
        travel = (np.max(r) - np.min(r)) / options.count_m
        if travel < 1e4 or not np.max(np.abs(r)) / options.count_m < 2.0 ** 61:
            raise UserError(f"--count-m: {options.count_m!r} m puts the known-answer motion "
                            f"({np.max(r) - np.min(r):.3g} m of travel, up to "
                            f"{np.max(np.abs(r)):.3g} m) on {travel:.3g} counts; the float "
                            f"build needs at least 1e4 counts of travel and positions within "
                            f"2^61 counts")
        with np.errstate(over="ignore", invalid="ignore"):
            uq = wf.apply(selftest.counts(r, options.count_m) * options.count_m)
        if not np.all(np.isfinite(uq)):
            raise UserError(f"{options.model_name}: the model's force on the known-answer motion "
                            f"in counts is not finite; not a usable model")


def float_build(wf: WindowFeedforward, count_m: float) -> dict:
    """What export.json says of the C float build (``-DCLM_FF_FLOAT``): its input and the error
    docs/export.md measured for it."""
    return {"reference": f"int64 counts of {count_m!r} m", "count_m": count_m,
            "error": "vs the double build on the same counts, of the peak force on r2 (n_l = 16 "
                     "run): LIP 1e-7; PGNN 4e-7 (clm_ff), 3e-6 (stream); see docs/export.md"}


def export(model_path, to: str, out, *, ts: float | None = None,
           filter_tail: float | None = None, prefix: str | None = None,
           max_force: float | None = None, max_slew: float | None = None,
           max_velocity: float | None = None, max_acceleration: float | None = None,
           position_range: tuple | None = None, limits_from=None, no_limits: bool = False,
           count_m: float | None = None, onnx_form: str = "window") -> list[Path]:
    """Export the feedforward at ``model_path`` as ``to`` (``c`` or ``onnx``) into folder
    ``out`` (replaced as a whole; an earlier export there is replaced). ``filter_tail``: where a
    PGNN's feature filter is cut (the discarded tail's share of its sum; default 1e-15, i.e.
    rounding): a larger value shortens the window and the look-ahead and costs accuracy
    (docs/export.md). ``prefix``: the names of every public symbol and macro and of the files
    (default ``clm_ff``). The C's limits: ``max_force`` (N), ``max_velocity`` (m/s),
    ``max_acceleration`` (m/s^2), ``position_range`` (m, lower and upper), each by default the
    envelope of the data the model was fitted on widened by its margin (that data from
    ``limits_from``, a record, else found beside the model; :func:`resolve_limits`);
    ``no_limits``: none; ``max_slew`` (N/s): none by default. ``count_m`` (m): one count of the
    C float build's fixed-point reference (default 1e-12); ``onnx_form``: ``window`` (the
    reference window in, as the C) or ``mlp`` (the filtered features in, MatMul/Add/Tanh only).
    Returns the files."""
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
    lo, hi = position_range if position_range is not None else (None, None)
    given = {"max_force": max_force, "max_slew": max_slew, "r_min": lo, "r_max": hi,
             "v_max": max_velocity, "a_max": max_acceleration}
    count_m = DEFAULT_COUNT_M if count_m is None else count_m
    options = ExportOptions(prefix=DEFAULT_PREFIX if prefix is None else prefix,
                            count_m=count_m, **given)  # checked before reading
    if to == "onnx" and (any(v is not None for v in given.values()) or no_limits
                         or limits_from is not None):
        raise UserError("--max-force/--max-slew/--max-velocity/--max-acceleration/"
                        "--position-range/--limits-from/--no-limits: the limits are part of the "
                        "C export only (an ONNX runtime applies its own)")
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
    out = Path(out)
    try:
        # the model (and the .pt or .json beside it) would be deleted with an earlier export
        with atomic_folder(out, what="an exported feedforward",
                           subdirs=(), inputs=(model_path,)) as tmp:
            if to == "c":
                limits, where, envelope = resolve_limits(model_path, wf, given,
                                                         no_limits=no_limits,
                                                         limits_from=limits_from)
            else:
                limits, where = dict.fromkeys(LIMIT_KEYS), "none (ONNX)"
                envelope = training_envelope(model_path, wf)
            options = ExportOptions.traced(model_path, prefix=options.prefix, count_m=count_m,
                                           envelope=where, **limits)
            check_vectors(wf, options, envelope, c=to == "c")
            names = [p.name for p in writer(wf, tmp, options)]
            (tmp / "export.json").write_text(json.dumps({
                "model": options.model_name, "kind": wf.kind, "to": to, "ts": wf.ts,
                "lag": wf.lag, "lead": wf.lead,
                "filter_tail": wf.filter.get("tol") if wf.filter.get("cutoff_hz") else None,
                "prefix": options.prefix, **options.limits(), "limits_from": where,
                **({"float_build": float_build(wf, options.count_m)} if to == "c" else
                   {"onnx_form": onnx_form}),
                "trace": options.trace(), "files": names,
                "description": safe_text(wf.describe())},
                indent=1))
    except OSError as exc:
        raise UserError(f"{out}: cannot write the export ({exc.strerror or exc})") from None
    return [out / n for n in names]
