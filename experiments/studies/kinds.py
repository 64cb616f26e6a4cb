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

import functools
from pathlib import Path

from clm_sim.errors import UserError
from clm_sim.schema import build, load_yaml


@functools.cache
def declared() -> dict[str, tuple[str, object]]:
    """kind -> (its section, its package) of every study package under ``experiments/studies/``
    (a folder whose ``__init__.py`` sets ``KIND``), in the packages' name order. Importing a
    package costs nothing: its study module is imported by its ``study()``."""
    import importlib
    import pkgutil

    import experiments.studies as studies

    found = {}
    for info in pkgutil.iter_modules(studies.__path__):
        if info.ispkg:
            package = importlib.import_module(f"{studies.__name__}.{info.name}")
            if hasattr(package, "KIND"):
                found[package.KIND] = (package.SECTION, package)
    return found


def sections() -> dict[str, str]:
    """kind -> the section its settings go under."""
    return {kind: section for kind, (section, _) in declared().items()}


def study_for(path):
    """The :class:`~experiments.studies.protocol.Study` that the config at ``path`` names (only
    that study's module is imported); ``UserError`` naming the file when it names none."""
    kind = kind_of(load_yaml(path), path)
    return declared()[kind][1].study()


def kind_of(data: dict, path) -> str:
    """The kind of the study config ``data`` read from ``path``; ``UserError`` (naming the file)
    for an unknown kind, a section of another kind, or no way to tell."""
    kinds = sections()
    kind = data.get("kind")
    found = [s for s in kinds.values() if s in data]
    if kind is None:  # as before kind: existed; without a section, load_study says what is missing
        by_section = {section: name for name, section in kinds.items()}
        if len(found) > 1:
            a, b = found[:2]
            raise UserError(f"{path}: kind: missing; a config with both '{a}:' and '{b}:' says "
                            f"which study it is with 'kind: {by_section[a]}' or "
                            f"'kind: {by_section[b]}'")
        return by_section[found[0]] if found else "extrapolation"
    if not isinstance(kind, str) or kind not in kinds:
        raise UserError(f"{path}: kind: expected one of {', '.join(kinds)}, got {kind!r}")
    other = [s for s in found if s != kinds[kind]]
    if other:
        raise UserError(f"{path}: {other[0]}: not a setting of 'kind: {kind}' (its settings go "
                        f"under '{kinds[kind]}:')")
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
            why = NOT_READ[key].format(section=sections()[kind])
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
    section (:func:`sections`) as ``settings_type``, and every reference key that
    ``references(settings)`` names defined under ``references:``. Errors name the file and key."""
    from experiments.config import ExperimentConfig

    path = Path(path)
    section = sections()[kind]
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


def preflighted(load):
    """``load`` followed by the checks ``clm-sim run`` makes before any computation
    (:func:`experiments.runner.preflight`), errors naming the file."""
    def checked(path):
        from experiments.runner import preflight

        config, settings = load(path)
        try:
            preflight(config)
        except UserError as exc:
            raise UserError(f"{path}: {exc}") from None
        return config, settings
    return checked
