"""What the study kinds share in reading their configs: the ``kind:`` a loader takes off, the
sections of an experiment config that no study reads (refused, not ignored), the loader of a
study whose cases set the plant, and ``clm-sim run``'s checks before any work.

Which study a config is (its ``kind:``, or its section for a config without one) is
:func:`experiments.studies.runner.kind_of`; each kind is declared by its own package.
"""

from __future__ import annotations

from pathlib import Path

from clm_sim.errors import UserError
from clm_sim.schema import build, load_yaml


# Sections of an experiment config that no study reads (each study sets its own models, the
# references it replays and its simulated records under its section): refused, not ignored.
NOT_READ = {
    "feedforwards": "it trains the models its '{section}:' section sets",
    "replay": "the references it uses are named under '{section}:'",
    "data": "it simulates its records; identification from measured records is 'clm-sim run' "
            "with a data: section",
}


def refuse_unread(data: dict, kind: str, section: str, keys=tuple(NOT_READ)) -> None:
    """Refuse (one line naming it) a section of :data:`NOT_READ` among ``keys`` of the study
    config ``data`` of ``kind`` (whose settings go under ``section``)."""
    for key in keys:
        if key in data:
            why = NOT_READ[key].format(section=section)
            raise UserError(f"{key}: not used by the {kind} study ({why}); remove it")


def take_kind(data: dict, path, expected: str) -> dict:
    """``data`` without its ``kind:``, which must be ``expected`` (or absent)."""
    data = dict(data)
    kind = data.pop("kind", None)
    if kind is not None and kind != expected:
        raise UserError(f"{path}: kind: {kind!r} is not a {expected} study")
    return data


def load_case_study(path, kind: str, section: str, settings_type, references):
    """``(config, settings)`` of a study whose cases set the plant (the failure map, the
    mechanism study): an experiment config without plant effects or ``truth:``, the study's
    ``section`` as ``settings_type``, and every reference key that
    ``references(settings)`` names defined under ``references:``. Errors name the file and key."""
    from experiments.config import ExperimentConfig

    path = Path(path)
    data = take_kind(load_yaml(path), path, kind)
    raw = data.pop(section, None)
    try:
        if "effects" in (data.get("plant") or {}):
            raise UserError(f"plant.effects: the effects are set per case under {section}.cases")
        if data.get("truth") is not None:
            raise UserError(f"truth: not supported by the {kind} study (the cases set the plant)")
        refuse_unread(data, kind, section, ("data",))  # before the build: its checks assume a run on it
        config = build(ExperimentConfig, data, "config")
        refuse_unread(data, kind, section)
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
