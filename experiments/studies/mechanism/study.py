"""Why lambda = 0 does what it does beyond the training range: finding (iii) over training
records, the drift's mechanism shown, and a control experiment.

Finding (iii) of the PGNN paper: beyond the training range a PGNN trained without the pull
toward theta_LIP (lambda = 0) tracks worse than one with it (lambda = 0.01). This study asks it
with both rows on one cost (``mechanism.pgnn``; default the paper's: no network weight decay, no
continuation start), so the two rows differ in lambda alone, and with the training record as the
unit of replication:

* ``records`` training records (dither seeds ``seed, seed + 1, ...``; each its own LIP), and
  ``draws`` network draws per record; lambda = 0 and lambda = ``lam`` share the record and the
  draw (paired);
* per case (a plant: ``cases`` name -> its parasitic effects), the r2-minus-r1 question is the
  paired difference of MAE on the ``outside`` reference, ``lam - 0``. Its interval is a
  two-level (cluster) bootstrap: records resampled with replacement, then draws within each
  chosen record, so it covers both sources of variation; the same for the log ratio. The p-value
  is the t-test on the per-record means (records are the independent units), Holm-adjusted over
  the cases.

The mechanism, per fit: the static force (v = a = 0, the dwell) against position out to the
outside reference's reach, split into the physical part ``theta . filt(T)`` and the network,
beside the LIP and the true plant force (the simulator's oracle). The network's best
linear-in-features part is its least-squares projection on ``[filt T, 1]`` over the training
data; the rest is its remainder. ``cubic`` coefficients are least-squares fits of ``c0 + c1 y +
c2 y^2 + c3 y^3`` over the static curve inside the training range: the remainder's ``c3`` is
what the drift builds, the truth's is what there is to build (the default plant's cable carrier,
2000 N/m^3). A case whose effects have no such term (a linear cable) is the control.
The true force is the plant's motor command (``Plant.motor_command``: exact where an effect
scales the motor force, as a track end does). A static curve holds v = a = 0; the study also
prints, per model, the rms force error along the outside reference where it is beyond the
range, against the command that reference's exact motion needs (accelerations included).

``clm-sim study CONFIG`` runs it for ``kind: mechanism`` (settings under ``mechanism:``,
:mod:`~experiments.studies.mechanism.settings`); the cells (:mod:`~experiments.studies.
mechanism.cells`) are summarized (:mod:`~experiments.studies.mechanism.summary`) into a
:class:`~experiments.studies.mechanism.result.MechanismResult`. ``mechanism.json``,
``report.md`` (:mod:`~experiments.studies.mechanism.report`), ``config.resolved.yaml`` and
``figures/force_beyond.png`` (:mod:`~experiments.studies.mechanism.figures`) are written into
the output folder.
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

from clm_sim.schema import to_plain
from experiments.config import ExperimentConfig, resolved
from experiments.processes.workers import cores
from experiments.studies.kinds import preflighted
from experiments.studies.mechanism.cells import compute
from experiments.studies.mechanism.figures import draw
from experiments.studies.mechanism.report import report
from experiments.studies.mechanism.result import MechanismResult
from experiments.studies.mechanism.settings import MechanismSettings, load_mechanism
from experiments.studies.mechanism.summary import summarize
from experiments.studies.protocol import Study


def _compute(config: ExperimentConfig, settings: MechanismSettings, *, workers: int,
             progress) -> tuple[MechanismResult, None]:
    """Every cell, summarized and timed."""
    start = time.perf_counter()
    cells = compute(config, settings, workers=workers, progress=progress)
    result = summarize(settings, cells)
    return replace(result, wall_time_s=time.perf_counter() - start, cells=tuple(cells)), None


def _figures(result: MechanismResult, folder: Path, scene=None) -> None:
    draw(list(result.cells), result.settings, folder / "force_beyond.png")


STUDY = Study(
    kind="mechanism", section="mechanism", what="a clm-sim mechanism study",
    settings=MechanismSettings, load=preflighted(load_mechanism), compute=_compute,
    result=MechanismResult, result_file="mechanism.json", report=report, figures=_figures,
    resolved=lambda config, settings: {**resolved(config), "mechanism": to_plain(settings)},
    workers=cores)
