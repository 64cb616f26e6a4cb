"""The mechanism study's cells: one task per (case, training record, draws), run in a worker
process; per fit its MAE, its static force split into the physical part, the network's linear
part and its remainder, and (with ``near_linear``) the unit-by-unit view and intervention."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, replace

import numpy as np

from clm_sim.features import TrainingRange
from experiments.config import ExperimentConfig
from experiments.studies.mechanism.result import (CellLip, CellResult, EffectBeyond, Fit,
                                                   StaticSplit)
from experiments.studies.mechanism.settings import MechanismSettings
from experiments.testbed import Testbed


@dataclass(frozen=True)
class Cell:
    """One task: a case, a training record and its network ``draws`` (both lambdas each;
    ``None``: every draw)."""

    config: ExperimentConfig
    settings: MechanismSettings
    case: str
    record: int
    draws: tuple[int, ...] | None = None


def cubic(y: np.ndarray, f: np.ndarray) -> float:
    """The y^3 coefficient (N/m^3) of a least-squares cubic in ``y`` (m) through ``f`` (N)."""
    return float(np.polynomial.polynomial.polyfit(y, f, 3)[3])


def static_parts(model, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Physical part ``theta . T`` and network part (N) of a PGNN at rest (v = a = 0) at
    positions ``y`` (m): the force it holds at a dwell."""
    phi = np.zeros((len(y), 4))
    phi[:, 3] = y
    return phi @ np.array([model.theta_[k] for k in ("mass", "viscous", "coulomb",
                                                     "stiffness")]), model.network(phi)


def linear_part(model, phi: np.ndarray) -> np.ndarray:
    """The network's best linear-in-features part: least-squares coefficients of its output on
    ``[phi, 1]`` over the training columns ``phi`` (N, 4), in the order a, v, sign v, y, 1."""
    cols = np.column_stack([phi, np.ones(len(phi))])
    return np.linalg.lstsq(cols, model.network(phi), rcond=None)[0]


def _cell(cell: Cell) -> CellResult:
    from controllers.pgnn import training_data

    st = cell.settings
    config = replace(cell.config, plant=replace(cell.config.plant,
                                                effects=st.cases[cell.case]))
    tb = Testbed(config)
    ts = config.ts
    run = tb.training_run(seed=cell.record)
    lip = tb.fit_lip(run)
    settings = asdict(st.pgnn)  # Python names (lam, continuation_lam), as fit_pgnn takes them
    data = training_data(config.features, y=run.y, u=run.u, ts=run.ts,
                         decimation=settings.get("decimation"))
    inside = TrainingRange.of(config.features, tb.reference(st.inside), ts)
    reach = float(np.max(np.abs(tb.reference(st.outside))))
    y = np.linspace(-reach, reach, st.grid_points)
    within = np.abs(y) <= inside.position_m
    beyond = ~within
    zeros = np.zeros_like(y)
    truth = tb.machine.motor_command(y, zeros, zeros)  # exact where an effect scales u
    lip_static = lip.theta_["stiffness"] * y

    def rms_beyond(f, side=None):
        """rms error beyond the range; ``side`` -1 or +1: below -limit or above +limit only."""
        where = beyond if side is None else beyond & (np.sign(y) == side)
        return float(np.sqrt(np.mean((f - truth)[where] ** 2)))

    # The force along the outside reference where it is beyond the range, against the motor
    # command its exact motion needs: what a static curve misses where an effect scales m*a.
    sig = config.references[st.outside].sample(ts)
    along = np.abs(sig.r) > inside.position_m
    need = tb.machine.motor_command(sig.r, sig.v, sig.a)

    def rms_along(model):
        return float(np.sqrt(np.mean((model.feedforward(sig.r, ts) - need)[along] ** 2)))

    beyond_effects = effects_beyond(config, tb, st)
    cell_lip = CellLip(theta=dict(lip.theta_), error_beyond_rms_n=rms_beyond(lip_static),
                       error_along_rms_n=rms_along(lip),
                       need_along_rms_n=float(np.sqrt(np.mean(need[along] ** 2))),
                       mae={r: tb.replay(lip, r).mae for r in (st.inside, st.outside)})
    fits = []
    for draw in range(st.draws) if cell.draws is None else cell.draws:
        for lam in (0.0, st.lam):
            given = {k: v for k, v in settings.items() if k != "lam"}
            if lam == 0.0 and st.zero_lam_diag:
                given["lam_diag"] = dict(st.zero_lam_diag)
            model = tb.fit_pgnn(run, hidden=st.hidden, lam=lam, seed=draw, lip=lip, **given)
            phys, net = static_parts(model, y)
            coef = linear_part(model, data.phi)
            lin = coef[3] * y + coef[4]
            rest = net - lin
            total = phys + net
            fit = Fit(
                draw=draw, lam=lam, stop=model.fit_.stop, iterations=model.fit_.iterations,
                data_cost=model.fit_.data_cost, theta=dict(model.theta_),
                mae={r: tb.replay(model, r).mae for r in (st.inside, st.outside)},
                error_beyond_rms_n=rms_beyond(total),
                error_beyond_sides_rms_n=[rms_beyond(total, -1), rms_beyond(total, 1)],
                error_along_rms_n=rms_along(model),
                dwell_force_n=float(np.interp(reach, y, total)),
                drift_stiffness=model.theta_["stiffness"] - lip.theta_["stiffness"],
                network_linear=dict(zip(("mass", "viscous", "coulomb", "stiffness", "offset"),
                                        map(float, coef))),
                remainder_cubic=cubic(y[within], rest[within]),
                model_cubic=cubic(y[within], total[within]),
                static=StaticSplit(phys.tolist(), net.tolist(), lin.tolist(), rest.tolist()))
            if st.near_linear is not None:
                fit = replace(fit, units=_units(model, data.phi, y, phys, truth, within,
                                                st.near_linear, rms_along, tb, st.outside))
            fits.append(fit)
    return CellResult(case=cell.case, record=cell.record, position_limit_m=inside.position_m,
                      effects_beyond=beyond_effects, y=y.tolist(), truth=truth.tolist(),
                      lip_static=lip_static.tolist(), lip=cell_lip,
                      truth_cubic=cubic(y[within], truth[within]), fits=tuple(fits))


def effects_beyond(config: ExperimentConfig, tb: Testbed,
                   st: MechanismSettings) -> dict[str, EffectBeyond]:
    """Per effect of the plant, the rms force (N) that the LIP's columns (a, v, sign v, y, 1)
    do not hold: the effect's force along the exact motion minus its least-squares projection
    on those columns over the inside reference; on the inside reference and along the outside
    one where it is beyond the range."""
    from clm_sim.features import lip_regressors

    ts = config.ts
    limit = TrainingRange.of(config.features, tb.reference(st.inside), ts).position_m
    sig_in, sig_out = (config.references[k].sample(ts) for k in (st.inside, st.outside))
    cols = lambda g: np.column_stack([lip_regressors(g.r, g.v, g.a), np.ones(len(g.r))])  # noqa
    beyond = np.abs(sig_out.r) > limit
    out = {}
    for k, effect in enumerate(config.plant.effects):
        force = [effect.force(g.r, g.v, tb.machine.motor_command(g.r, g.v, g.a))
                 for g in (sig_in, sig_out)]
        coef = np.linalg.lstsq(cols(sig_in), force[0], rcond=None)[0]
        rest_in = force[0] - cols(sig_in) @ coef
        rest_out = (force[1] - cols(sig_out) @ coef)[beyond]
        out[f"{k}:{effect.type}"] = EffectBeyond(
            inside_rms_n=float(np.sqrt(np.mean(rest_in ** 2))),
            beyond_rms_n=float(np.sqrt(np.mean(rest_out ** 2))))
    return out


class _LinedFeedforward:
    """A PGNN whose named units act as their training lines (the intervention), replayed."""

    def __init__(self, model, units, fitted_lines):
        self.model, self.units, self.lines = model, units, fitted_lines

    def feedforward(self, r, ts):
        from clm_sim.features import held_force
        from experiments.studies.mechanism.units import network_with_lines

        phi = self.model.filtered_features(y=r, ts=ts)
        theta = np.array([self.model.theta_[k] for k in ("mass", "viscous", "coulomb",
                                                          "stiffness")])
        return held_force(phi @ theta + network_with_lines(self.model, phi, self.units,
                                                           self.lines))


def _units(model, phi_train, y, phys, truth, within, near_linear, rms_along, tb, outside):
    """The unit-by-unit view of one fit and the intervention with its control: per arm, the
    static force error beyond and inside the range (rms, N), the force error along the outside
    reference beyond the range and its MAE."""
    from experiments.studies.mechanism import units
    grid = np.zeros((len(y), 4))
    grid[:, 3] = y
    v = units.view(model, phi_train, grid[~within], near_linear)
    fl = np.asarray(v["lines"])
    arms = {}
    for arm in ("named", "control"):
        total = phys + units.network_with_lines(model, grid, v[arm], fl)
        ff = _LinedFeedforward(model, v[arm], fl)
        arms[arm] = {
            "units": v[arm],
            "error_beyond_rms_n": float(np.sqrt(np.mean((total - truth)[~within] ** 2))),
            "error_inside_rms_n": float(np.sqrt(np.mean((total - truth)[within] ** 2))),
            "error_along_rms_n": rms_along(ff),
            "mae_outside": tb.replay(ff, outside).mae}
    total = phys + model.network(grid)
    arms["none"] = {"error_inside_rms_n": float(np.sqrt(np.mean((total - truth)[within] ** 2)))}
    return {"view": v["units"], "intervention": arms}


def run_cell(cell: Cell) -> CellResult:
    """One cell in a worker process (single-threaded torch)."""
    import torch

    torch.set_num_threads(1)
    out = _cell(cell)
    json.dumps(out.to_json(), allow_nan=False)  # a NaN in the results is a bug
    return out


def cells(config: ExperimentConfig, settings: MechanismSettings, parts: int = 1) -> list[Cell]:
    """Every task in a fixed order (case, record, draws); records are ``seed, seed + 1, ...``.
    ``parts`` > 1 splits each record's draws into that many tasks of consecutive draws (each
    simulates the record and fits its LIP again: a few seconds against its fits)."""
    parts = max(1, min(parts, settings.draws))
    split = [tuple(map(int, d)) for d in np.array_split(np.arange(settings.draws), parts)]
    return [Cell(config, settings, case, config.seed + k, None if parts == 1 else draws)
            for case in settings.cases for k in range(settings.records) for draws in split]


def parts_for(settings: MechanismSettings, workers: int) -> int:
    """Tasks per record for ``workers`` processes: one, unless the records leave a process
    idle at the end (5 records on 2 workers: the last record alone for a fifth of the run);
    then ``workers``, so the tasks come out even."""
    n = len(settings.cases) * settings.records
    return 1 if workers <= 1 or n % workers == 0 else workers


def merged(results: list[CellResult]) -> list[CellResult]:
    """The results of the tasks of :func:`cells` as one per (case, record), every draw's fits
    in draw order: what the record computed in one task gives (the rest of a record's result
    is the same in each of its tasks: the same training run, LIP and replays)."""
    out: list[CellResult] = []
    for r in results:
        if out and (out[-1].case, out[-1].record) == (r.case, r.record):
            out[-1] = replace(out[-1], fits=out[-1].fits + r.fits)
        else:
            out.append(r)
    return out


def compute(config: ExperimentConfig, settings: MechanismSettings, *, workers: int = 1,
            progress=None) -> list[CellResult]:
    """Every cell (in ``workers`` processes when > 1), in task order; the results do not depend
    on ``workers`` (a record split over tasks, :func:`parts_for`, is merged back)."""
    from experiments.processes.workers import map_in_order

    progress = progress or (lambda message: None)
    tasks = cells(config, settings, parts_for(settings, workers))

    def said(done, i, _):
        t = tasks[i]
        which = "" if t.draws is None else f", draws {t.draws[0]}-{t.draws[-1]}"
        progress(f"cell {done}/{len(tasks)}: {t.case}, record {t.record}{which}")
    return merged(map_in_order(run_cell, tasks, workers, said))
