"""``clm-sim study CONFIG``: one runner for every study kind (:class:`~experiments.studies.
protocol.Study`).

The config's kind names the study (:func:`study_for`); the runner
reads it (errors name the file and key, before any work), checks the output folder, computes
(``--workers`` processes where the study runs a pool; progress on stderr), and writes into a
folder replaced atomically (:func:`clm_sim.outdir.atomic_folder`: an interruption leaves the
previous folder as it was): ``config.resolved.yaml``, the result's JSON, ``report.md`` and the
figures. Then it prints the report's findings and where the report is.
"""

from __future__ import annotations

import functools
import json
from pathlib import Path

from clm_sim.errors import UserError
from clm_sim.schema import load_yaml
from experiments.studies.protocol import Study


@functools.cache
def declared() -> dict[str, tuple[str, object]]:
    """kind -> (its section, its ``kind`` module) of every study package under
    ``experiments/studies/`` (each has a ``kind.py``: ``KIND``, ``SECTION``, ``study()``), in
    the packages' name order. The walk costs nothing: a study's module is imported by its
    ``study()``, for the one kind a config names."""
    import importlib
    import pkgutil

    import experiments.studies as studies

    found = {}
    for info in pkgutil.iter_modules(studies.__path__):
        if info.ispkg:
            kind = importlib.import_module(f"{studies.__name__}.{info.name}.kind")
            found[kind.KIND] = (kind.SECTION, kind)
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


def run(study: Study, config_path, out=None, *, workers: int | None = None,
        quiet: bool = False):
    """Run ``study`` on ``config_path`` into ``out`` (default ``results/<config stem>``);
    returns its result. Nothing is written when the config is refused."""
    import yaml

    from clm_sim.outdir import atomic_folder, check_output_folder
    from experiments.testbed import Progress

    config, settings = study.load(config_path)
    out = Path(out) if out else Path("results") / Path(config_path).stem
    inputs = study.inputs(config_path, settings)
    check_output_folder(out, what=study.what, inputs=inputs)  # before the work
    progress = Progress(quiet)
    pool = {}
    if study.workers is not None:
        pool = {"workers": workers or study.workers()}
    result, scene = study.compute(config, settings, progress=progress, **pool)
    with atomic_folder(out, what=study.what, inputs=inputs) as tmp:
        (tmp / "config.resolved.yaml").write_text(yaml.safe_dump(
            study.resolved(config, settings), sort_keys=False))
        (tmp / study.result_file).write_text(
            json.dumps(result.to_json(), indent=1, **dict(study.json_options)))
        study.figures(result, tmp / "figures", scene)
        (tmp / "report.md").write_text(study.report(result, settings))
    progress(f"report in {out}/report.md")
    if study.summary is None:
        from experiments.report.screen import report_summary

        print(report_summary(out), end="")
    else:
        print(study.summary(result, out))
    return result


def main(config_path, out=None, *, workers: int | None = None, quiet: bool = False) -> int:
    """``clm-sim study CONFIG``: the study the config's ``kind:`` names, run; its exit code."""
    study = study_for(config_path)
    return study.exit_code(run(study, config_path, out, workers=workers, quiet=quiet))
