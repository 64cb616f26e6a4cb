"""Which study a study config is: its ``kind:`` says so.

``kind: extrapolation`` (the lambda study; settings under ``study:``), ``kind: failure_map``
(where lambda = 0 fails; settings under ``failure_map:``) or ``kind: emps_benchmark`` (EMPS on the
field's benchmark protocol; settings under ``benchmark:``) or ``kind: mechanism`` (finding (iii)
over training records and its mechanism; settings under ``mechanism:``) or
``kind: identifiability`` (converged profiles of the data cost at lambda = 0; settings under
``identifiability:``). A config written before ``kind:``
existed is still read by its section (none: the extrapolation study; two sections without a
``kind:`` are refused).
"""

from __future__ import annotations

from pathlib import Path

from clm_sim.errors import UserError
from clm_sim.schema import build, load_yaml

KINDS = {"extrapolation": "study", "failure_map": "failure_map",  # kind -> its section
         "emps_benchmark": "benchmark", "mechanism": "mechanism",
         "identifiability": "identifiability"}
MODULES = {"extrapolation": "extrapolation.study", "failure_map": "failure_map.study",  # kind ->
           "emps_benchmark": "emps.benchmark", "mechanism": "mechanism.study",  # its module in
           "identifiability": "profiles.study"}  # experiments.studies
POOLED = {"failure_map", "mechanism", "identifiability", "emps_benchmark"}  # kinds whose main() takes workers=


def kind_of(data: dict, path) -> str:
    """The kind of the study config ``data`` read from ``path``; ``UserError`` (naming the file)
    for an unknown kind, a section of another kind, or no way to tell."""
    kind = data.get("kind")
    sections = [s for s in KINDS.values() if s in data]
    if kind is None:  # as before kind: existed; without a section, load_study says what is missing
        by_section = {section: name for name, section in KINDS.items()}
        if len(sections) > 1:
            a, b = sections[:2]
            raise UserError(f"{path}: kind: missing; a config with both '{a}:' and '{b}:' says "
                            f"which study it is with 'kind: {by_section[a]}' or "
                            f"'kind: {by_section[b]}'")
        return by_section[sections[0]] if sections else "extrapolation"
    if not isinstance(kind, str) or kind not in KINDS:
        raise UserError(f"{path}: kind: expected one of {', '.join(KINDS)}, got {kind!r}")
    other = [s for s in sections if s != KINDS[kind]]
    if other:
        raise UserError(f"{path}: {other[0]}: not a setting of 'kind: {kind}' (its settings go "
                        f"under '{KINDS[kind]}:')")
    return kind


# Sections of an experiment config that no study reads (each study sets its own models, the
# references it replays and its simulated records under its section): refused, not ignored.
NOT_READ = {
    "feedforwards": "it trains the models its '{section}:' section sets",
    "replay": "the references it uses are named under '{section}:'",
    "data": "it simulates its records; identification from measured records is 'clm-sim run' "
            "with a data: section",
}


def refuse_unread(data: dict, kind: str, keys=tuple(NOT_READ)) -> None:
    """Refuse (one line naming it) a section of :data:`NOT_READ` among ``keys`` of the study
    config ``data`` of ``kind``."""
    for key in keys:
        if key in data:
            why = NOT_READ[key].format(section=KINDS[kind])
            raise UserError(f"{key}: not used by the {kind} study ({why}); remove it")


def take_kind(data: dict, path, expected: str) -> dict:
    """``data`` without its ``kind:``, which must be ``expected`` (or absent)."""
    data = dict(data)
    kind = data.pop("kind", None)
    if kind is not None and kind != expected:
        raise UserError(f"{path}: kind: {kind!r} is not a {expected} study")
    return data


def load_case_study(path, kind: str, settings_type, references):
    """``(config, settings)`` of a study whose cases set the plant (the failure map, the
    mechanism study): an experiment config without plant effects or ``truth:``, the study's
    section (``KINDS[kind]``) as ``settings_type``, and every reference key that
    ``references(settings)`` names defined under ``references:``. Errors name the file and key."""
    from experiments.config import ExperimentConfig

    path = Path(path)
    section = KINDS[kind]
    data = take_kind(load_yaml(path), path, kind)
    raw = data.pop(section, None)
    try:
        if "effects" in (data.get("plant") or {}):
            raise UserError(f"plant.effects: the effects are set per case under {section}.cases")
        if data.get("truth") is not None:
            raise UserError(f"truth: not supported by the {kind} study (the cases set the plant)")
        refuse_unread(data, kind, ("data",))  # before the build: its checks assume a run on it
        config = build(ExperimentConfig, data, "config")
        refuse_unread(data, kind)
        settings = build(settings_type, raw, section)
    except UserError as exc:
        raise UserError(f"{path}: {str(exc).removeprefix('config.').removeprefix('config: ')}") \
            from None
    for key in references(settings):
        if key not in config.references:
            raise UserError(f"{path}: {section}: reference {key!r} is not defined under "
                            f"'references'")
    return config, settings


def run_checked(config_path, out, load, run, *, workers: int | None = None,
                quiet: bool = False):
    """``clm-sim study CONFIG`` for a study run on an experiment config: ``load(config_path)``
    gives ``(config, settings)``, the checks ``clm-sim run`` makes before any computation (errors
    name the file), ``run(config, settings, out, workers=, quiet=)`` into ``out`` (default
    ``results/<config stem>``); prints the report's findings and where the report is, and
    returns the run's result."""
    from clm_sim.outdir import check_writable
    from experiments.report.screen import report_summary
    from experiments.runner import preflight

    config, settings = load(config_path)
    try:
        preflight(config)
    except UserError as exc:
        raise UserError(f"{config_path}: {exc}") from None
    out = Path(out) if out else Path("results") / Path(config_path).stem
    check_writable(out, inputs=(config_path,))  # before the work
    result = run(config, settings, out, workers=workers, quiet=quiet)
    print(report_summary(out), end="")
    return result
