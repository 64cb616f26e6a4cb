"""Where does lambda = 0 fail? The failure map of the PGNN paper's finding (iii).

Finding (iii): outside the training range a PGNN trained without regularization (lambda = 0)
tracks much worse than one regularized toward theta_LIP (lambda = 0.01). This study measures the
ratio ``MAE(lambda = 0) / MAE(lambda = lam)`` on references that leave the training range, over
the factors that decide it:

* the parasitic force of the plant (one case per set of effects, e.g. none, cable carrier,
  cogging, force ripple, Stribeck), which decides what the network has to learn;
* the direction of extrapolation (a reference per direction: position r2, velocity r3);
* the network size n_l.

Pairing. For each case and seed there is one training run (its dither drawn from the seed) and
one LIP; for each n_l the two PGNNs start from the same random hidden layer. So the two MAEs of
one seed share everything but lambda, and the comparison is paired by seed: the interval is a
t-interval on the per-seed log ratio ``ln MAE(0) - ln MAE(lam)`` (a ratio is what the paper's
claim is about, and the log makes it symmetric), transformed back to a ratio. A cell is
``holds`` when the whole interval lies above 1, ``reversed`` when it lies below 1, else
``undecided``; Holm's correction over all extrapolation cells is reported beside it.

``clm-sim study CONFIG`` dispatches here when the config has a ``failure_map:`` section
(:class:`~experiments.studies.failure_map.settings.FailureMapSettings`); the cells (case x n_l
x seed) are independent and run on a process pool (``experiments.processes.workers.map_in_order``,
one thread per worker). The result is a typed
:class:`~experiments.studies.failure_map.result.FailureMapResult`; the output folder holds
``failure_map.json`` (its ``to_json``), ``report.md``, ``config.resolved.yaml`` and
``figures/*.png``.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from clm_sim.features import TrainingRange
from clm_sim.plant import THETA_NAMES
from clm_sim.schema import to_plain
from controllers.pgnn_settings import FILE_KEYS
from experiments.config import ExperimentConfig, resolved
from experiments.processes.workers import cores
from experiments.results import BeyondRange, error_beyond_rms
from experiments.stats.paired import LogRatio, Paired, holm
from experiments.studies.failure_map.result import (BothFits, CellFailure, CellStats, Drift,
                                                    FailureMapResult, FitRow, Interval, Mechanism,
                                                    NetworkBeyond, ThetaDrift)
from experiments.studies.failure_map.report import report
from experiments.studies.failure_map.settings import FailureMapSettings
from experiments.studies.kinds import load_case_study, preflighted
from experiments.studies.protocol import Study
from experiments.sweeps.store import code_version
from experiments.testbed import Testbed

if TYPE_CHECKING:  # the record type, for annotations only
    from controllers.pgnn.fit_record import FitRecord


def load_failure_map(path) -> tuple[ExperimentConfig, FailureMapSettings]:
    """Read a failure-map config; errors name the file and the key."""
    return load_case_study(path, "failure_map", "failure_map", FailureMapSettings,
                           lambda settings: (settings.inside, *settings.outside.values()))


# ----------------------------------------------------------------------------- one cell

@dataclass(frozen=True)
class Cell:
    """One independent task: a case, a network size and a seed (both lambdas, paired)."""

    config: ExperimentConfig
    settings: FailureMapSettings
    case: str
    hidden: int
    seed: int


def fit_entry(record: FitRecord) -> dict:
    """A fit as ``failure_map.json`` keeps it: why it stopped (``converged`` or not), its
    iterations, costs (N**2), last gradient norm and how many starts it ran."""
    return {"stop": record.stop, "iterations": record.iterations,
            "data_cost": record.data_cost, "reg_cost": record.reg_cost,
            "grad_norm": record.grad_norm, "restarts": record.restarts}


@dataclass(frozen=True)
class Fitted:
    """One lambda's PGNN in a cell: its lambda, theta_phy (named, SI units), MAE per reference
    (m), its force against the training range per reference and its fit record."""

    lam: float
    theta: dict[str, float]
    mae: dict[str, float]
    beyond: dict[str, BeyondRange]
    fit: FitRecord

    def to_json(self) -> dict:
        return {FILE_KEYS["lam"]: self.lam, "theta": self.theta, "mae": self.mae,
                "parts": {k: {"network_peak_beyond_n": b.network_peak_beyond_n,
                              "network_peak_within_n": b.network_peak_within_n,
                              "error_beyond_rms_n": b.error_beyond_rms_n}
                          for k, b in self.beyond.items()},
                "fit": fit_entry(self.fit)}


@dataclass(frozen=True)
class CellResult:
    """A computed cell: its case, n_l and seed, the training ranges, the LIP (theta, MAE per
    reference, its error against the true force beyond the range) and the PGNN without
    regularization (``unregularized``, lambda = 0) and with it (``regularized``), paired."""

    case: str
    hidden: int
    seed: int
    ranges: dict
    lip_theta: dict[str, float]
    lip_mae: dict[str, float]
    lip_error_beyond_rms_n: dict[str, float | None]
    unregularized: Fitted
    regularized: Fitted

    def to_json(self) -> dict:
        return {"case": self.case, "hidden": self.hidden, "seed": self.seed,
                "ranges": self.ranges,
                "lip": {"theta": self.lip_theta, "mae": self.lip_mae,
                        "error_beyond_rms_n": self.lip_error_beyond_rms_n},
                "unregularized": self.unregularized.to_json(),
                "regularized": self.regularized.to_json()}


def run_cell(cell: Cell) -> CellResult | CellFailure:
    """Compute one cell in a worker (single-threaded torch). Never raises for the cell's own
    failure: a :class:`CellFailure` is returned instead, so the others go on."""
    try:
        import torch

        threads = torch.get_num_threads()
        torch.set_num_threads(1)  # one core per cell; cells run in parallel
        try:
            out = _cell(cell)
        finally:
            torch.set_num_threads(threads)
        json.dumps(out.to_json(), allow_nan=False)  # a NaN in the results is a failure
        return out
    except Exception as exc:  # noqa: BLE001 (recorded, not raised: the other cells go on)
        text = " ".join(str(exc).split()) or type(exc).__name__
        return CellFailure(case=cell.case, hidden=cell.hidden, seed=cell.seed,
                           error=f"{type(exc).__name__}: {text}")


def _cell(cell: Cell) -> CellResult:
    st = cell.settings
    config = replace(cell.config, plant=replace(cell.config.plant,
                                                effects=st.cases[cell.case]))
    tb = Testbed(config)
    ts = config.ts
    run = tb.training_run(seed=cell.seed)
    lip = tb.fit_lip(run)
    names = (st.inside, *st.outside.values())
    refs = {k: tb.reference(k) for k in names}
    inside = TrainingRange.of(config.features, refs[st.inside], ts)
    beyond, truth = {}, {}
    for k, r in refs.items():
        y, v, a = config.features.motion(r, ts)
        truth[k] = tb.machine.inverse_force(y, v, a)  # the simulator's oracle force
        beyond[k] = inside.beyond(config.features, r, ts)

    pgnn = dataclasses.asdict(st.pgnn)

    def fitted(lam: float) -> Fitted:
        # seed=0: the network's stream is (the run's seed, 0), so both lambdas start from the
        # same random hidden layer; the pairing rests on it.
        model = tb.fit_pgnn(run, hidden=cell.hidden, lam=lam, seed=0, lip=lip, **pgnn)
        return Fitted(lam=lam, theta={k: float(v) for k, v in model.theta_.items()},
                      mae={k: tb.replay(model, k).mae for k in names},
                      beyond={k: BeyondRange.of(*model.predict_parts(y=r, ts=ts), beyond[k],
                                                truth[k]) for k, r in refs.items()},
                      fit=model.fit_)

    return CellResult(
        case=cell.case, hidden=cell.hidden, seed=cell.seed, ranges=inside.as_dict(),
        lip_theta=lip.theta_, lip_mae={k: tb.replay(lip, k).mae for k in names},
        lip_error_beyond_rms_n={k: error_beyond_rms(lip.predict(y=r, ts=ts), truth[k], beyond[k])
                                for k, r in refs.items()},
        unregularized=fitted(0.0), regularized=fitted(st.lam))


# ----------------------------------------------------------------------------- statistics

def verdict(ratio: LogRatio) -> str:
    """``holds`` (interval above 1: lambda = 0 loses), ``reversed`` (below 1) or ``undecided``."""
    return "holds" if ratio.low > 1 else "reversed" if ratio.high < 1 else "undecided"


def summarize(settings: FailureMapSettings,
              results: list[CellResult | CellFailure]) -> FailureMapResult:
    """The failure map from the cell results (any order): per case, direction and n_l the
    paired ratio with its interval and verdict, the mechanism numbers and every fit's stop."""
    ok = [r for r in results if isinstance(r, CellResult)]
    failures = tuple(r for r in results if isinstance(r, CellFailure))
    by = {(r.case, r.hidden): sorted((x for x in ok if (x.case, x.hidden) == (r.case, r.hidden)),
                                     key=lambda x: x.seed)
          for r in ok}
    directions = {**{d: ref for d, ref in settings.outside.items()},
                  "inside": settings.inside}
    cells, drift, fits = [], {}, []
    for case in settings.cases:
        for hidden in settings.hidden:
            rows = by.get((case, hidden), [])
            for r in rows:
                for f in (r.unregularized, r.regularized):
                    fits.append(FitRow(case=case, hidden=hidden, seed=r.seed, lam=f.lam,
                                       **fit_entry(f.fit)))
            if len(rows) < 2:
                continue
            drift[(case, hidden)] = _drift(rows)
            for direction, ref in directions.items():
                cells.append(_cell_stats(settings, case, hidden, direction, ref, rows))
    adjusted = iter(holm([c.ratio.p for c in cells if c.outside]))
    for i, c in enumerate(cells):
        if c.outside:
            p = next(adjusted)
            cells[i] = replace(c, p_holm=p, holm_significant=p < 1 - settings.confidence)
    return FailureMapResult(
        settings=settings,
        interval=(f"{settings.confidence:.0%} t-interval on the per-seed log ratio "
                  "ln MAE(lambda=0) - ln MAE(lambda), paired by seed (same training run and "
                  "network initialization); p-values two-sided, Holm-adjusted over the "
                  "extrapolation cells"),
        cells=tuple(cells), drift=drift, fits=tuple(fits), failures=failures,
        mechanism=_mechanism([c for c in cells if c.outside]))


def _mean(values):
    values = [v for v in values if v is not None]
    return float(np.mean(values)) if values else None


def _cell_stats(settings, case, hidden, direction, ref, rows) -> CellStats:
    a = [r.unregularized.mae[ref] for r in rows]
    b = [r.regularized.mae[ref] for r in rows]
    pair = Paired.of(a, b, settings.confidence)
    ratio = pair.log_ratio  # MAEs are positive and a cell has >= 2 seeds

    def network(which: str) -> NetworkBeyond:
        return NetworkBeyond(**{q: _mean([getattr(getattr(r, which).beyond[ref], q) for r in rows])
                                for q in ("network_peak_beyond_n", "network_peak_within_n",
                                          "error_beyond_rms_n")})

    stops = [f.fit.stop for r in rows for f in (r.unregularized, r.regularized)]
    return CellStats(
        case=case, hidden=hidden, direction=direction, reference=ref,
        seeds=tuple(r.seed for r in rows), mae=BothFits(tuple(a), tuple(b)),
        mae_lip_mean=float(np.mean([r.lip_mae[ref] for r in rows])), ratio=ratio,
        difference_m=Interval(mean=pair.diff, low=pair.ci[0], high=pair.ci[1]),
        verdict=verdict(ratio),
        network=BothFits(network("unregularized"), network("regularized")),
        lip_error_beyond_rms_n=_mean([r.lip_error_beyond_rms_n[ref] for r in rows]),
        capped_fits=stops.count("max_iter"),
        unconverged_fits=sum(x != "converged" for x in stops))


def _drift(rows) -> Drift:
    """theta_phy - theta_LIP per parameter (SI units), mean and spread over seeds, and the force
    it moves at the edge of the training range (N): the parameter times the largest |feature|
    of the training reference (|a|, |v|, 1, |y|)."""
    edge = rows[0].ranges
    scale = {"mass": edge["acceleration_m_s2"], "viscous": edge["velocity_m_s"],
             "coulomb": 1.0, "stiffness": edge["position_m"]}

    def of(which: str) -> dict[str, ThetaDrift]:
        d = {k: [getattr(r, which).theta[k] - r.lip_theta[k] for r in rows] for k in THETA_NAMES}
        return {k: ThetaDrift(mean=float(np.mean(v)), std=float(np.std(v, ddof=1)),
                              edge_force_n=float(np.mean(np.abs(v)) * scale[k]))
                for k, v in d.items()}

    return Drift(theta_lip={k: float(np.mean([r.lip_theta[k] for r in rows]))
                            for k in THETA_NAMES},
                 theta=BothFits(of("unregularized"), of("regularized")))


def _mechanism(outside: list[CellStats]) -> Mechanism:
    """How the MAE ratio follows the model's force error beyond the range: Spearman's rank
    correlation over the extrapolation cells of ln(MAE ratio) with
    ln(error_beyond(lambda = 0) / error_beyond(lambda))."""
    from scipy import stats

    xs, ys = [], []
    for c in outside:
        e0 = c.network.unregularized.error_beyond_rms_n
        e1 = c.network.regularized.error_beyond_rms_n
        if e0 and e1:
            xs.append(math.log(e0 / e1))
            ys.append(c.ratio.log_mean)
    if len(xs) < 3:
        return Mechanism(n_cells=len(xs), spearman=None)
    rho = stats.spearmanr(xs, ys)
    return Mechanism(n_cells=len(xs), spearman=float(rho.statistic))


# ----------------------------------------------------------------------------- running

def cells(config: ExperimentConfig, settings: FailureMapSettings) -> list[Cell]:
    """Every task, in a fixed order (case, n_l, seed); seeds are 1..seeds offset by the config's
    seed so that two configs can draw disjoint seeds."""
    return [Cell(config, settings, case, hidden, config.seed + s)
            for case in settings.cases for hidden in settings.hidden
            for s in range(settings.seeds)]


def compute(config: ExperimentConfig, settings: FailureMapSettings, *, workers: int = 1,
            progress=None) -> list[CellResult | CellFailure]:
    """Run every cell (in ``workers`` processes when > 1) and return the results in task order.
    The results do not depend on ``workers``: each cell is deterministic and single-threaded."""
    from experiments.processes.workers import map_in_order

    progress = progress or (lambda message: None)
    tasks = cells(config, settings)

    def done(count, i, result):
        t = tasks[i]
        status = f"FAILED {result.error}" if isinstance(result, CellFailure) else "ok"
        progress(f"cell {count}/{len(tasks)}: {t.case}, n_l={t.hidden}, seed {t.seed}: {status}")

    return map_in_order(run_cell, tasks, workers, done)


def _compute(config: ExperimentConfig, settings: FailureMapSettings, *, workers: int,
             progress) -> tuple[FailureMapResult, None]:
    """Every cell, summarized: the map, with the wall time, the workers and the code version."""
    start = time.perf_counter()
    results = compute(config, settings, workers=workers, progress=progress)
    result = replace(summarize(settings, results),
                     wall_time_s=time.perf_counter() - start, workers=workers,
                     code_version=code_version())  # the sources that computed the cells
    return result, None


# ----------------------------------------------------------------------------- figures

def draw(result: FailureMapResult, folder: Path, scene=None) -> None:
    """The report's figures (:func:`failure_map_figures`) as PNG files."""
    from experiments import plots
    from experiments.studies.failure_map.figures import failure_map_figures

    for stem, fig in failure_map_figures(result).items():
        plots.save(fig, Path(folder) / f"{stem}.png")


STUDY = Study(
    kind="failure_map", section="failure_map", what="a clm-sim failure map",
    settings=FailureMapSettings, load=preflighted(load_failure_map), compute=_compute,
    result=FailureMapResult, result_file="failure_map.json", report=report, figures=draw,
    resolved=lambda config, settings: {**resolved(config), "failure_map": to_plain(settings)},
    workers=cores, exit_code=lambda result: 1 if result.failures else 0)
