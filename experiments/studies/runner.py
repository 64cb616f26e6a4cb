"""``clm-sim study CONFIG``: one runner for every study kind (:class:`~experiments.studies.
protocol.Study`).

The config's kind names the study (:func:`experiments.studies.kinds.study_for`); the runner
reads it (errors name the file and key, before any work), checks the output folder, computes
(``--workers`` processes where the study runs a pool; progress on stderr), and writes into a
folder replaced atomically (:func:`clm_sim.outdir.atomic_folder`: an interruption leaves the
previous folder as it was): ``config.resolved.yaml``, the result's JSON, ``report.md`` and the
figures. Then it prints the report's findings and where the report is.
"""

from __future__ import annotations

import json
from pathlib import Path

from experiments.studies.protocol import Study


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
    from experiments.studies.kinds import study_for

    study = study_for(config_path)
    return study.exit_code(run(study, config_path, out, workers=workers, quiet=quiet))
