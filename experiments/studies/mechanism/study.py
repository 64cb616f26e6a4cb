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

``clm-sim study CONFIG`` dispatches here when the config has a ``mechanism:`` section;
``mechanism.json``, ``report.md``, ``config.resolved.yaml`` and ``figures/force_beyond.png``
are written into the output folder.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import ClassVar

import numpy as np
import scipy.stats
import yaml

from clm_sim.effects.base import Effect
from clm_sim.effects.position import CableSlab
from clm_sim.errors import UserError
from clm_sim.features import TrainingRange
from clm_sim.outdir import atomic_folder
from clm_sim.plant import THETA_UNITS
from clm_sim.schema import to_plain
from controllers.pgnn_settings import LAMBDA_KEYS, PerParameter, PGNNSettings
from experiments.config import ExperimentConfig, resolved
from experiments.processes.workers import cores
from experiments.studies.kinds import load_case_study, run_checked
from experiments.table import holm
from experiments.testbed import Progress, Testbed


def _default_cases() -> dict[str, tuple[Effect, ...]]:
    return {"cable_cubic": (CableSlab(coefficients=(0.0, 10.0, 0.0, 2000.0)),),
            "cable_linear": (CableSlab(coefficients=(0.0, 10.0)),)}


@dataclass(frozen=True)
class MechanismSettings:
    """The ``mechanism:`` section of a config.

    cases: name -> the parasitic effects of the plant (they replace ``plant.effects``);
    records: training records (dither seeds) per case, >= 2; draws: network draws per record,
    >= 1; hidden: n_l; lam: the lambda compared with 0 (> 0); inside / outside: the training
    reference and the one that leaves its range; pgnn: the fit settings shared by both rows
    (default: the paper's cost); bootstrap: resamples of the two-level bootstrap; confidence:
    level of the intervals; grid_points: positions of the static force curve; zero_lam_diag
    (``lambda0_diag:`` in a config): per-parameter pulls toward theta_LIP given to the lambda = 0
    row only, e.g. ``{stiffness: 0.01}``: that row then holds those parameters and leaves the rest
    free, a control that acts on one parameter's drift and keeps the plant (None: none);
    near_linear: the unit-by-unit view and its intervention
    (:mod:`experiments.studies.mechanism.units`): a hidden unit whose pre-activation stays within
    +-near_linear on the training samples is near-linear (None: no view); prediction: per case, the
    numbers written before the run (:mod:`experiments.studies.mechanism.prediction`:
    ``mae_diff_um``, ``error_beyond_lambda0_n``, ``error_beyond_lambda_n``, and ``factor``, how far
    the measured amount may lie from the predicted one), which the report sets beside the outcome.
    """

    cases: dict[str, tuple[Effect, ...]] = field(default_factory=_default_cases)
    records: int = 5
    draws: int = 2
    hidden: int = 16
    lam: float = 0.01
    inside: str = "r1"
    outside: str = "r2"
    pgnn: PGNNSettings = field(default_factory=lambda: PGNNSettings(
        weight_decay=0.0, continuation_lam=0.0))
    bootstrap: int = 4000
    confidence: float = 0.95
    grid_points: int = 69
    zero_lam_diag: dict[str, float] | None = None
    near_linear: float | None = None
    prediction: dict[str, dict[str, float]] | None = None
    aliases: ClassVar[dict[str, str]] = {"lambda": LAMBDA_KEYS["lambda"],  # config -> field
                                         "lambda0_diag": "zero_lam_diag"}

    def __post_init__(self):
        if not self.cases:
            raise UserError("cases: expected at least one case")
        for key, low in (("records", 2), ("draws", 1), ("hidden", 1), ("bootstrap", 100),
                         ("grid_points", 11)):
            value = getattr(self, key)
            if not (isinstance(value, int) and not isinstance(value, bool) and value >= low):
                raise UserError(f"{key}: expected an integer >= {low}, got {value!r}")
        if not self.lam > 0:
            raise UserError(f"lambda: expected a number > 0, got {self.lam!r}")
        if not 0.5 <= self.confidence < 1:
            raise UserError(f"confidence: expected a level in [0.5, 1), got {self.confidence!r}")
        if self.zero_lam_diag is not None:
            if not PerParameter().accepts(self.zero_lam_diag) or not any(
                    v > 0 for v in self.zero_lam_diag.values()):
                raise UserError(f"lambda0_diag: expected {PerParameter().describe()}, one of "
                                f"them > 0, got {self.zero_lam_diag!r}")
            # A pull on the lambda = 0 row also turns its continuation start off (it runs only
            # without one): with a start on, the rows would differ in two settings.
            if self.pgnn.continuation_lam > 0:
                raise UserError(f"lambda0_diag: needs pgnn.continuation_lambda: 0 (got "
                                f"{self.pgnn.continuation_lam:g}); with a continuation start "
                                f"the held row would differ in two settings")
        if self.near_linear is not None and not (
                isinstance(self.near_linear, (int, float)) and self.near_linear > 0):
            raise UserError(f"near_linear: expected a number > 0, got {self.near_linear!r}")
        for case, p in (self.prediction or {}).items():
            if case not in self.cases:
                raise UserError(f"prediction.{case}: not a case (cases: {', '.join(self.cases)})")
            missing = {"mae_diff_um", "error_beyond_lambda0_n", "error_beyond_lambda_n",
                       "factor"} - set(p)
            if missing:
                raise UserError(f"prediction.{case}: expected the keys "
                                f"{', '.join(sorted(missing))}")
            if not p["factor"] > 1:
                raise UserError(f"prediction.{case}.factor: expected a number > 1, got "
                                f"{p['factor']!r}")
        if self.outside == self.inside:
            raise UserError(f"outside: {self.inside!r} is the inside reference; an outside "
                            f"reference leaves the training range")


def load_mechanism(path) -> tuple[ExperimentConfig, MechanismSettings]:
    """Read a mechanism config; errors name the file and the key."""
    return load_case_study(path, "mechanism", MechanismSettings,
                           lambda settings: (settings.inside, settings.outside))


# ----------------------------------------------------------------------------- one cell

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


def _cell(cell: Cell) -> dict:
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

    out = {"case": cell.case, "record": cell.record, "position_limit_m": inside.position_m,
           "effects_beyond": effects_beyond(config, tb, st),
           "y": y.tolist(), "truth": truth.tolist(), "lip_static": lip_static.tolist(),
           "lip": {"theta": dict(lip.theta_), "error_beyond_rms_n": rms_beyond(lip_static),
                   "error_along_rms_n": rms_along(lip),
                   "need_along_rms_n": float(np.sqrt(np.mean(need[along] ** 2))),
                   "mae": {r: tb.replay(lip, r).mae for r in (st.inside, st.outside)}},
           "truth_cubic": cubic(y[within], truth[within]), "fits": []}
    for draw in range(st.draws) if cell.draws is None else cell.draws:
        for lam in (0.0, st.lam):
            fit = {k: v for k, v in settings.items() if k != "lam"}
            if lam == 0.0 and st.zero_lam_diag:
                fit["lam_diag"] = dict(st.zero_lam_diag)
            model = tb.fit_pgnn(run, hidden=st.hidden, lam=lam, seed=draw, lip=lip, **fit)
            phys, net = static_parts(model, y)
            coef = linear_part(model, data.phi)
            lin = coef[3] * y + coef[4]
            rest = net - lin
            total = phys + net
            out["fits"].append({
                "draw": draw, "lambda": lam, "stop": model.fit_.stop,
                "iterations": model.fit_.iterations, "data_cost": model.fit_.data_cost,
                "theta": dict(model.theta_),
                "mae": {r: tb.replay(model, r).mae for r in (st.inside, st.outside)},
                "error_beyond_rms_n": rms_beyond(total),
                "error_beyond_sides_rms_n": [rms_beyond(total, -1), rms_beyond(total, 1)],
                "error_along_rms_n": rms_along(model),
                "dwell_force_n": float(np.interp(reach, y, total)),
                "drift_stiffness": model.theta_["stiffness"] - lip.theta_["stiffness"],
                "network_linear": dict(zip(("mass", "viscous", "coulomb", "stiffness",
                                            "offset"), map(float, coef))),
                "remainder_cubic": cubic(y[within], rest[within]),
                "model_cubic": cubic(y[within], total[within]),
                "static": {"physical": phys.tolist(), "network": net.tolist(),
                           "network_linear": lin.tolist(), "remainder": rest.tolist()}})
            if st.near_linear is not None:
                out["fits"][-1]["units"] = _units(model, data.phi, y, phys, truth, within,
                                                  st.near_linear, rms_along, tb, st.outside)
    return out


def effects_beyond(config: ExperimentConfig, tb: Testbed, st: MechanismSettings) -> dict:
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
        out[f"{k}:{effect.type}"] = {
            "inside_rms_n": float(np.sqrt(np.mean(rest_in ** 2))),
            "beyond_rms_n": float(np.sqrt(np.mean(rest_out ** 2)))}
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


def run_cell(cell: Cell) -> dict:
    """One cell in a worker process (single-threaded torch)."""
    import torch

    torch.set_num_threads(1)
    out = _cell(cell)
    json.dumps(out, allow_nan=False)
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


def merged(results: list[dict]) -> list[dict]:
    """The results of the tasks of :func:`cells` as one per (case, record), every draw's fits
    in draw order: what the record computed in one task gives (the rest of a record's result
    is the same in each of its tasks: the same training run, LIP and replays)."""
    out: list[dict] = []
    for r in results:
        if out and (out[-1]["case"], out[-1]["record"]) == (r["case"], r["record"]):
            out[-1]["fits"].extend(r["fits"])
        else:
            out.append({**r, "fits": list(r["fits"])})
    return out


# ----------------------------------------------------------------------------- statistics

def cluster_bootstrap(values: list[list[float]], resamples: int, confidence: float,
                      rng: np.random.Generator) -> dict:
    """Mean of ``values[record][draw]`` and its percentile interval from a two-level bootstrap:
    records with replacement, then draws with replacement within each chosen record."""
    vals = [np.asarray(v, dtype=float) for v in values]
    n = len(vals)
    means = np.empty(resamples)
    for b in range(resamples):
        pick = rng.integers(0, n, n)
        means[b] = np.mean([vals[i][rng.integers(0, len(vals[i]), len(vals[i]))].mean()
                            for i in pick])
    tail = 50 * (1 - confidence)
    lo, hi = np.percentile(means, [tail, 100 - tail])
    return {"mean": float(np.mean([v.mean() for v in vals])), "ci": [float(lo), float(hi)]}


def _record_t(values: list[list[float]]) -> float | None:
    per_record = [float(np.mean(v)) for v in values]
    if len(per_record) < 2 or np.std(per_record) == 0:
        return None
    return float(scipy.stats.ttest_1samp(per_record, 0.0).pvalue)


def record_t_interval(values: list[list[float]], confidence: float) -> list[float] | None:
    """The t-interval of the mean over the per-record means of ``values[record][draw]``: the
    interval of the p column's test. With few records a percentile bootstrap over them is
    narrower than it should be (it never sees a record mean beyond the ones it has), so this
    one is printed beside it."""
    per_record = np.array([float(np.mean(v)) for v in values])
    if len(per_record) < 2:
        return None
    half = (scipy.stats.t.ppf(0.5 + confidence / 2, len(per_record) - 1)
            * per_record.std(ddof=1) / np.sqrt(len(per_record)))
    return [float(per_record.mean() - half), float(per_record.mean() + half)]


def paired_median(values: list[list[float]]) -> dict:
    """Median of paired differences ``values[record][draw]`` and how many are above zero: the
    force error beyond the range is heavy-tailed (one network that explodes beyond the range
    carries a mean of fifty pairs), so its mean is printed beside these, not alone."""
    flat = [x for v in values for x in v]
    return {"median": float(np.median(flat)), "higher": int(sum(x > 0 for x in flat)),
            "n": len(flat)}


def summarize(settings: MechanismSettings, results: list[dict]) -> dict:
    """Per case: finding (iii) over records x draws (difference and log ratio of MAE on the
    outside reference, lam - 0, and of the static force error beyond the range), the per-record
    means, and the mechanism's medians; Holm over the cases."""
    rng = np.random.default_rng(0)  # the bootstrap's own stream: same results, same intervals
    out, pvals = {}, []
    ref = settings.outside
    for case in settings.cases:
        cell_list = [r for r in results if r["case"] == case]
        pairs = []  # per record: [(fit lam0, fit reg), ...]
        for r in cell_list:
            by = {(f["draw"], f["lambda"]): f for f in r["fits"]}
            pairs.append([(by[(d, 0.0)], by[(d, settings.lam)]) for d in range(settings.draws)])
        diff = [[b["mae"][ref] - a["mae"][ref] for a, b in p] for p in pairs]
        logr = [[np.log(b["mae"][ref] / a["mae"][ref]) for a, b in p] for p in pairs]
        err = [[b["error_beyond_rms_n"] - a["error_beyond_rms_n"] for a, b in p] for p in pairs]
        boot_lr = cluster_bootstrap(logr, settings.bootstrap, settings.confidence, rng)
        fits = [f for r in cell_list for f in r["fits"]]

        def med(lam, key, sub=None):
            vals = [f[key] if sub is None else f[key][sub] for f in fits if f["lambda"] == lam]
            return float(np.median(vals))

        rows = {}
        for name, lam in (("lambda=0", 0.0), (f"lambda={settings.lam:g}", settings.lam)):
            rows[name] = {
                "mae_inside_um": med(lam, "mae", settings.inside) * 1e6,
                "mae_outside_um": med(lam, "mae", ref) * 1e6,
                "error_beyond_rms_n": med(lam, "error_beyond_rms_n"),
                "error_along_rms_n": med(lam, "error_along_rms_n"),
                "dwell_force_n": med(lam, "dwell_force_n"),
                "drift_stiffness": med(lam, "drift_stiffness"),
                "network_linear_stiffness": med(lam, "network_linear", "stiffness"),
                "model_linear_stiffness_minus_lip": float(np.median(
                    [f["drift_stiffness"] + f["network_linear"]["stiffness"]
                     for f in fits if f["lambda"] == lam])),
                "remainder_cubic": med(lam, "remainder_cubic"),
                "model_cubic": med(lam, "model_cubic"),
                # how far each parameter travelled (median |theta - theta_LIP| over the fits):
                # a control that holds one parameter shows here where the drift went instead
                "theta_moved": {k: float(np.median(
                    [abs(f["theta"][k] - r["lip"]["theta"][k])
                     for r in cell_list for f in r["fits"] if f["lambda"] == lam]))
                    for k in cell_list[0]["lip"]["theta"]},
                "converged": sum(f["stop"] == "converged" for f in fits if f["lambda"] == lam),
                "fits": sum(f["lambda"] == lam for f in fits)}
        lip = {"mae_inside_um": float(np.median([r["lip"]["mae"][settings.inside]
                                                 for r in cell_list])) * 1e6,
               "mae_outside_um": float(np.median([r["lip"]["mae"][ref]
                                                  for r in cell_list])) * 1e6,
               "error_beyond_rms_n": float(np.median([r["lip"]["error_beyond_rms_n"]
                                                      for r in cell_list])),
               "error_along_rms_n": float(np.median([r["lip"]["error_along_rms_n"]
                                                     for r in cell_list])),
               "need_along_rms_n": float(np.median([r["lip"]["need_along_rms_n"]
                                                    for r in cell_list]))}
        every = [f for f in fits]
        rho = scipy.stats.spearmanr([f["mae"][ref] for f in every],
                                    [f["error_beyond_rms_n"] for f in every])
        worst = max(fits, key=lambda f: f["error_beyond_rms_n"])
        worst_record = next(r["record"] for r in cell_list if any(f is worst for f in r["fits"]))
        p = _record_t(diff)
        pvals.append(p)
        out[case] = {
            "effects": [e.as_config() for e in settings.cases[case]],
            "truth_cubic": float(np.median([r["truth_cubic"] for r in cell_list])),
            "truth_dwell_force_n": float(np.median([np.interp(max(r["y"]), r["y"], r["truth"])
                                                    for r in cell_list])),
            "records": [r["record"] for r in cell_list], "draws": settings.draws,
            "mae_outside_diff": {**cluster_bootstrap(diff, settings.bootstrap,
                                                     settings.confidence, rng),
                                 "per_record": [float(np.mean(d)) for d in diff],
                                 "lam_lower": int(sum(x < 0 for d in diff for x in d)),
                                 "n": int(sum(len(d) for d in diff)), "p_records_t": p,
                                 "ci_records_t": record_t_interval(diff, settings.confidence)},
            "mae_outside_ratio": {"ratio": float(np.exp(boot_lr["mean"])),
                                  "ci": [float(np.exp(c)) for c in boot_lr["ci"]]},
            "error_beyond_diff": {**cluster_bootstrap(err, settings.bootstrap,
                                                      settings.confidence, rng),
                                  **paired_median(err)},
            "spearman_mae_vs_force_error": float(rho.statistic),
            # the fit that carries a heavy tail, and on which side of the range its error is
            "worst_error_beyond": {"record": worst_record, "draw": worst["draw"],
                                   "lambda": worst["lambda"],
                                   "rms_n": worst["error_beyond_rms_n"],
                                   "sides_rms_n": worst["error_beyond_sides_rms_n"],
                                   "mae_outside_um": worst["mae"][ref] * 1e6,
                                   "error_along_rms_n": worst["error_along_rms_n"]},
            "rows": rows, "lip": lip,
            "effects_beyond": cell_list[0].get("effects_beyond")}
        if settings.near_linear is not None:
            out[case]["units"] = units_summary(settings, fits)
        if settings.prediction and case in settings.prediction:
            out[case]["prediction"] = outcome(settings.prediction[case], out[case])
    for case, p in zip(settings.cases, holm(pvals)):
        out[case]["mae_outside_diff"]["p_holm"] = p
    return {"cases": out, "settings": to_plain(settings)}


def units_summary(settings: MechanismSettings, fits: list[dict]) -> dict:
    """Per row: how many units the reading names (median, range), their share of the network's
    remainder force beyond the range, and the intervention against its control: medians of the
    static force error beyond and inside, the change of the error beyond per fit (arm minus
    none), and in how many fits the named arm changes it more (in absolute value) than the
    control."""
    out = {}
    for name, lam in (("lambda=0", 0.0), (f"lambda={settings.lam:g}", settings.lam)):
        rows = [f for f in fits if f["lambda"] == lam]
        n_named = [len(f["units"]["intervention"]["named"]["units"]) for f in rows]

        def share(f):
            view, named = f["units"]["view"], f["units"]["intervention"]["named"]["units"]
            tot = sum(u["remainder_beyond_rms_n"] ** 2 for u in view)
            return (sum(view[j]["remainder_beyond_rms_n"] ** 2 for j in named) / tot
                    if tot > 0 else 0.0)

        def delta(f, arm):
            return (f["units"]["intervention"][arm]["error_beyond_rms_n"]
                    - f["error_beyond_rms_n"])

        both = [f for f in rows if f["units"]["intervention"]["named"]["units"]]
        out[name] = {
            "named_median": float(np.median(n_named)), "named_range": [min(n_named),
                                                                        max(n_named)],
            "fits_with_named": len(both), "fits": len(rows),
            "named_share_beyond": float(np.median([share(f) for f in rows])),
            "error_beyond_none_n": float(np.median([f["error_beyond_rms_n"] for f in rows])),
            **{f"error_beyond_{arm}_n": float(np.median(
                [f["units"]["intervention"][arm]["error_beyond_rms_n"] for f in both]))
               if both else None for arm in ("named", "control")},
            **{f"error_inside_{arm}_n": float(np.median(
                [f["units"]["intervention"][arm]["error_inside_rms_n"] for f in both]))
               if both else None for arm in ("none", "named", "control")},
            **{f"delta_beyond_{arm}_n": float(np.median([delta(f, arm) for f in both]))
               if both else None for arm in ("named", "control")},
            **{f"mae_outside_{arm}_um": float(np.median(
                [f["units"]["intervention"][arm]["mae_outside"] for f in both])) * 1e6
               if both else None for arm in ("named", "control")},
            "mae_outside_none_um": float(np.median([f["mae"][settings.outside] for f in both]))
            * 1e6 if both else None,
            "named_lowers_more": int(sum(delta(f, "named") < min(0.0, delta(f, "control"))
                                         for f in both))}
    return out


def outcome(pred: dict, case: dict) -> dict:
    """The pre-registered prediction beside what the run measured: the sign holds when the
    t-interval on the per-record means of lambda - 0 lies wholly on the predicted side of zero;
    an amount holds when the measured value lies within ``factor`` of the predicted one (same
    sign)."""
    d = case["mae_outside_diff"]
    mean, ci = d["mean"] * 1e6, [c * 1e6 for c in d["ci_records_t"]]
    side = np.sign(pred["mae_diff_um"])
    f = pred["factor"]

    def within(measured, predicted):
        return bool(measured * predicted > 0 and 1 / f <= measured / predicted <= f)

    rows = list(case["rows"].values())
    out = {**pred, "measured_mae_diff_um": mean, "measured_ci_um": ci,
           "sign_held": bool(side * ci[0] > 0 and side * ci[1] > 0),
           "amount_held": within(mean, pred["mae_diff_um"]),
           "measured_error_beyond_lambda0_n": rows[0]["error_beyond_rms_n"],
           "measured_error_beyond_lambda_n": rows[1]["error_beyond_rms_n"],
           "error_beyond_lambda0_held": within(rows[0]["error_beyond_rms_n"],
                                               pred["error_beyond_lambda0_n"]),
           "error_beyond_lambda_held": within(rows[1]["error_beyond_rms_n"],
                                              pred["error_beyond_lambda_n"])}
    if "mae_diff_calibrated_um" in pred:
        out["calibrated_amount_held"] = within(mean, pred["mae_diff_calibrated_um"])
    return out


# ----------------------------------------------------------------------------- report

def _p(p) -> str:
    return "–" if p is None else f"{p:.2g}"


def zero_label(settings: dict) -> str:
    """How the report names the lambda = 0 row: "λ = 0", or with the parameters that
    ``lambda0_diag`` holds, "λ = 0, stiffness held"."""
    diag = settings.get("lambda0_diag", settings.get("zero_lam_diag")) or {}
    held = [k for k, v in diag.items() if v > 0]
    return "λ = 0" + (f", {' and '.join(held)} held" if held else "")


def report(s: dict) -> str:
    """The study's Markdown report: finding (iii) per case, then the mechanism table."""
    st = dict(s["settings"])
    st["lam"] = st.get("lam", st.get("lambda"))  # to_plain writes the config's name
    z = zero_label(st)
    diag = st.get("lambda0_diag", st.get("zero_lam_diag"))

    def row_label(name: str) -> str:  # summary's "lambda=0.01" as the report names it
        return z if name == "lambda=0" else name.replace("lambda=", "λ = ")

    out = [f"# Finding (iii) over training records, and its mechanism", "",
           f"Per case: {st['records']} training records (dither seeds) x {st['draws']} network "
           f"draws, n_l = {st['hidden']}; {z} and λ = {st['lam']:g} on one cost "
           f"(weight decay {st['pgnn']['weight_decay']:g}, continuation "
           f"{st['pgnn']['continuation_lambda']:g}), paired by record and draw. "
           + ("" if not diag else
              f"The row {z} is λ = 0 with the pull toward θ_LIP on "
              + ", ".join(f"{k} {v:g}" for k, v in diag.items())
              + " only (lambda0_diag): the other parameters are free. ")
           + f"Intervals: "
           f"{100 * st['confidence']:g} % two-level bootstrap (records, then draws within "
           f"them; {st['bootstrap']} resamples). p: t-test on the per-record means, Holm over "
           f"the cases.", "",
           f"| case | MAE {st['outside']}: λ = {st['lam']:g} − {z} [µm] | ratio λ = "
           f"{st['lam']:g} / {z} | per-record means [µm] | pairs with λ = {st['lam']:g} "
           f"lower | p (Holm) | static force error beyond the range, λ = {st['lam']:g} − {z} "
           f"[N]: median (pairs with λ = {st['lam']:g} higher); mean [interval] | "
           f"Spearman(MAE {st['outside']}, force error) |",
           "|---|---|---|---|---|---|---|---|"]
    for case, c in s["cases"].items():
        d, r, e = c["mae_outside_diff"], c["mae_outside_ratio"], c["error_beyond_diff"]
        out.append(f"| {case} | {d['mean'] * 1e6:+.3f} [{d['ci'][0] * 1e6:+.3f}, "
                   f"{d['ci'][1] * 1e6:+.3f}] | {r['ratio']:.3f} [{r['ci'][0]:.3f}, "
                   f"{r['ci'][1]:.3f}] | "
                   + ", ".join(f"{x * 1e6:+.3f}" for x in d["per_record"])
                   + f" | {d['lam_lower']}/{d['n']} | {_p(d['p_records_t'])} "
                   f"({_p(d.get('p_holm'))}) | {e['median']:+.2f} ({e['higher']}/{e['n']}); "
                   f"mean {e['mean']:+.2f} [{e['ci'][0]:+.2f}, {e['ci'][1]:+.2f}] | "
                   f"{c['spearman_mae_vs_force_error']:.2f} |")
    t_cis = [(case, c["mae_outside_diff"].get("ci_records_t")) for case, c in s["cases"].items()]
    if all(ci is not None for _, ci in t_cis):
        out += ["", f"The same difference's {100 * st['confidence']:g} % t-interval on the "
                f"per-record means (the p column's test; with {st['records']} records the "
                "bootstrap's percentile interval is the narrower of the two): "
                + "; ".join(f"{case} [{ci[0] * 1e6:+.3f}, {ci[1] * 1e6:+.3f}] µm"
                            for case, ci in t_cis) + "."]
    out += ["", "Largest static force error beyond the range, per case (the fit that a mean "
            "of the column above can rest on): "
            + "; ".join(f"{case}: record {w['record']}, draw {w['draw']}, λ = {w['lambda']:g}, "
                        f"{w['rms_n']:.4g} N rms (below the range {w['sides_rms_n'][0]:.4g}, "
                        f"above it {w['sides_rms_n'][1]:.4g}), MAE {st['outside']} "
                        f"{w['mae_outside_um']:.3f} µm, force error along {st['outside']} "
                        f"beyond the range {w['error_along_rms_n']:.3g} N"
                        for case, c in s["cases"].items()
                        for w in [c["worst_error_beyond"]]) + "."]
    out += ["", "**The mechanism** (medians over every fit of the case; static force at rest, "
            "v = a = 0, against position; 'beyond': positions outside the training range out "
            f"to the reach of {st['outside']}; Δfk: θ's stiffness minus the LIP's; network "
            "slope: the stiffness column of the network's best linear-in-features part on the "
            "training data; cubic: y³ coefficient of a cubic fitted over the training range, "
            "of the network's remainder (what the drift builds) and of the whole model):", "",
            "| case | row | MAE r1 [µm] | MAE r2 [µm] | force error beyond, rms [N] | force at "
            "the far dwell [N] | Δfk [N/m] | network slope [N/m] | Δfk + slope [N/m] | "
            "remainder cubic [N/m³] | model cubic [N/m³] | converged |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for case, c in s["cases"].items():
        lip = c["lip"]
        out.append(f"| {case} | true plant | – | – | – | {c['truth_dwell_force_n']:.2f} | – | – "
                   f"| – | – | {c['truth_cubic']:.0f} | – |")
        out.append(f"| {case} | LIP | {lip['mae_inside_um']:.3f} | {lip['mae_outside_um']:.3f} "
                   f"| {lip['error_beyond_rms_n']:.2f} | – | 0 | – | – | – | 0 | – |")
        for name, row in c["rows"].items():
            out.append(
                f"| {case} | {row_label(name)} | "
                f"{row['mae_inside_um']:.3f} | "
                f"{row['mae_outside_um']:.3f} | {row['error_beyond_rms_n']:.2f} | "
                f"{row['dwell_force_n']:.2f} | {row['drift_stiffness']:+.4g} | "
                f"{row['network_linear_stiffness']:+.4g} | "
                f"{row['model_linear_stiffness_minus_lip']:+.3g} | "
                f"{row['remainder_cubic']:.0f} | {row['model_cubic']:.0f} | "
                f"{row['converged']}/{row['fits']} |")
    out += ["", f"**The force along {st['outside']} beyond the range** (medians; rms over the "
            f"samples of {st['outside']} with |r| beyond the training range, of the "
            "feedforward minus the motor command the reference's exact motion needs, "
            "accelerations included; the static curve above holds v = a = 0):", "",
            "| case | rms of the needed command [N] | LIP error [N] | "
            + " | ".join(f"{row_label(n)} error [N]"
                         for n in next(iter(s["cases"].values()))["rows"]) + " |",
            "|---|---|---|" + "---|" * len(next(iter(s["cases"].values()))["rows"])]
    for case, c in s["cases"].items():
        lip = c["lip"]
        if "error_along_rms_n" not in lip:  # a summary written before this table
            continue
        out.append(f"| {case} | {lip['need_along_rms_n']:.2f} | {lip['error_along_rms_n']:.2f} | "
                   + " | ".join(f"{row['error_along_rms_n']:.2f}" for row in c["rows"].values())
                   + " |")
    moved = [(case, name, row["theta_moved"]) for case, c in s["cases"].items()
             for name, row in c["rows"].items() if "theta_moved" in row]
    if moved:
        out += ["", "How far θ_phy travelled (median over the fits of |θ − θ_LIP|; "
                + ", ".join(f"{k} {u}" for k, u in THETA_UNITS.items()) + "): "
                + "; ".join(f"{case}, {row_label(name)}: "
                            + ", ".join(f"{k} {v:.3g}" for k, v in m.items())
                            for case, name, m in moved) + "."]
    if all(c.get("effects_beyond") for c in s["cases"].values()):
        out += ["", "**Per effect, the force the LIP's columns do not hold** (rms of the effect's "
                "force along the exact motion minus its least-squares projection on a, v, "
                f"sign v, y, 1 over {st['inside']}; on {st['inside']}, and along "
                f"{st['outside']} beyond the range):", "",
                f"| case | effect | on {st['inside']} [N] | along {st['outside']} beyond [N] |",
                "|---|---|---|---|"]
        for case, c in s["cases"].items():
            for name, e in c["effects_beyond"].items():
                out.append(f"| {case} | {name.split(':', 1)[1]} | {e['inside_rms_n']:.3f} | "
                           f"{e['beyond_rms_n']:.3f} |")
    if any("units" in c for c in s["cases"].values()):
        out += ["", f"**Unit by unit** (medians over the fits; a unit is named near-linear when "
                f"its pre-activation stays within ±{st['near_linear']:g} on every training "
                "sample; share: the named units' part of the squared remainder force beyond the "
                "range; intervention: the named units' tanh replaced by their line over the "
                "training samples; control: as many unnamed units, those with the most remainder "
                "force on the training samples; Δ: error beyond, arm minus the fit itself, "
                "median over the fits that have named units):", "",
                "| case | row | named units (range) | fits with named | share beyond | static "
                "error beyond: fit / named / control [N] | Δ named / Δ control [N] | named "
                "lowers it more | static error inside: fit / named / control [N] | MAE "
                f"{st['outside']}: fit / named / control [µm] |",
                "|---|---|---|---|---|---|---|---|---|---|"]
        f3 = lambda x, p=".2f": "–" if x is None else format(x, p)  # noqa: E731
        for case, c in s["cases"].items():
            for name, u in c.get("units", {}).items():
                out.append(
                    f"| {case} | {row_label(name)} | {u['named_median']:g} "
                    f"({u['named_range'][0]}–{u['named_range'][1]}) | "
                    f"{u['fits_with_named']}/{u['fits']} | {u['named_share_beyond']:.2f} | "
                    f"{f3(u['error_beyond_none_n'])} / {f3(u['error_beyond_named_n'])} / "
                    f"{f3(u['error_beyond_control_n'])} | {f3(u['delta_beyond_named_n'], '+.2f')}"
                    f" / {f3(u['delta_beyond_control_n'], '+.2f')} | "
                    f"{u['named_lowers_more']}/{u['fits_with_named']} | "
                    f"{f3(u['error_inside_none_n'], '.3f')} / "
                    f"{f3(u['error_inside_named_n'], '.3f')} / "
                    f"{f3(u['error_inside_control_n'], '.3f')} | "
                    f"{f3(u['mae_outside_none_um'], '.3f')} / "
                    f"{f3(u['mae_outside_named_um'], '.3f')} / "
                    f"{f3(u['mae_outside_control_um'], '.3f')} |")
    for case, c in s["cases"].items():
        pr = c.get("prediction")
        if not pr:
            continue
        yes = lambda b: "held" if b else "did not hold"  # noqa: E731
        out += ["", f"**The prediction written before the run ({case})**: MAE {st['outside']}, "
                f"λ = {st['lam']:g} − {z}: {pr['mae_diff_um']:+.3f} µm"
                + (f" (calibrated on the cubic cable: {pr['mae_diff_calibrated_um']:+.3f} µm)"
                   if "mae_diff_calibrated_um" in pr else "")
                + f"; static force error beyond the range: {z} {pr['error_beyond_lambda0_n']:.2f}"
                f" N, λ = {st['lam']:g} {pr['error_beyond_lambda_n']:.2f} N; an amount holds "
                f"within a factor {pr['factor']:g}. Measured: {pr['measured_mae_diff_um']:+.3f}"
                f" µm (t-interval on the per-record means [{pr['measured_ci_um'][0]:+.3f}, "
                f"{pr['measured_ci_um'][1]:+.3f}]); errors beyond (medians) "
                f"{pr['measured_error_beyond_lambda0_n']:.2f} N and "
                f"{pr['measured_error_beyond_lambda_n']:.2f} N. The sign {yes(pr['sign_held'])}; "
                f"the amount {yes(pr['amount_held'])}"
                + (f"; the calibrated amount {yes(pr['calibrated_amount_held'])}"
                   if "calibrated_amount_held" in pr else "")
                + f"; {z}'s force error beyond {yes(pr['error_beyond_lambda0_held'])}; "
                f"λ = {st['lam']:g}'s {yes(pr['error_beyond_lambda_held'])}."]
    out += ["", "Figure: `figures/force_beyond.png` (first record, draw 0 of each case)."]
    return "\n".join(out) + "\n"


def draw(results: list[dict], settings: MechanismSettings, path: Path) -> None:
    """Per case (columns): the static force against position, beyond the range shaded: top,
    the true force, the LIP and the two lambdas; bottom, the lambda = 0 fit split into
    theta . T minus the LIP, the network's linear part and its remainder."""
    import matplotlib.pyplot as plt

    from experiments import plots

    first = {}
    for r in results:
        first.setdefault(r["case"], r)
    fig, axes = plt.subplots(2, len(first), figsize=(5 * len(first), 7), squeeze=False,
                             sharex=True)
    for j, (case, r) in enumerate(first.items()):
        y = np.asarray(r["y"]) * 1e3
        lip = np.asarray(r["lip_static"])
        f0 = next(f for f in r["fits"] if f["draw"] == 0 and f["lambda"] == 0.0)
        f1 = next(f for f in r["fits"] if f["draw"] == 0 and f["lambda"] == settings.lam)
        tot = {k: np.asarray(f["static"]["physical"]) + np.asarray(f["static"]["network"])
               for k, f in (("0", f0), ("1", f1))}
        top, bottom = axes[0, j], axes[1, j]
        top.plot(y, r["truth"], color=plots.PALETTE[0], ls="--", label="true force")
        top.plot(y, lip, color=plots.PALETTE[7], label="LIP")
        z = zero_label(asdict(settings))
        top.plot(y, tot["0"], color=plots.PALETTE[4], label=f"PGNN {z}")
        top.plot(y, tot["1"], color=plots.PALETTE[5], label=f"PGNN λ = {settings.lam:g}")
        bottom.plot(y, np.asarray(f0["static"]["physical"]) - lip, color=plots.PALETTE[1],
                    label=f"{z}: θ·T − LIP")
        bottom.plot(y, f0["static"]["network_linear"], color=plots.PALETTE[2],
                    label="network, linear part")
        bottom.plot(y, f0["static"]["remainder"], color=plots.PALETTE[3],
                    label="network remainder")
        bottom.plot(y, np.asarray(r["truth"]) - lip, color=plots.PALETTE[0], ls="--",
                    label="true − LIP")
        limit = r["position_limit_m"] * 1e3
        for ax in (top, bottom):
            for side in (-1, 1):
                ax.axvspan(side * limit, side * y.max(), color=plots.PALETTE[4], alpha=0.08)
            ax.grid(alpha=0.3)
            ax.set_ylabel("force [N]")
        top.set_title(f"{case}, record {r['record']}: static force at rest", fontsize=9,
                      loc="left")
        bottom.set_title(f"{zero_label(asdict(settings))} fit, split", fontsize=9, loc="left")
        bottom.set_xlabel("position [mm]")
        top.legend(fontsize=7, loc="upper left")
        bottom.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    plots.save(fig, path)


# ----------------------------------------------------------------------------- running

def compute(config: ExperimentConfig, settings: MechanismSettings, *, workers: int = 1,
            progress=None) -> list[dict]:
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


def run_mechanism(config: ExperimentConfig, settings: MechanismSettings, out, *,
                  workers: int | None = None, quiet: bool = False) -> dict:
    """Run the study and write it into ``out`` (replaced atomically). Returns the summary."""
    progress = Progress(quiet)
    out = Path(out)
    workers = workers or cores()
    with atomic_folder(out, what="a clm-sim mechanism study") as tmp:
        (tmp / "config.resolved.yaml").write_text(yaml.safe_dump(
            {**resolved(config), "mechanism": to_plain(settings)}, sort_keys=False))
        start = time.perf_counter()
        results = compute(config, settings, workers=workers, progress=progress)
        summary = summarize(settings, results)
        summary["wall_time_s"] = time.perf_counter() - start
        (tmp / "mechanism.json").write_text(json.dumps(
            {**summary, "cells": [{k: v for k, v in r.items()} for r in results]}, indent=1))
        draw(results, settings, tmp / "figures" / "force_beyond.png")
        (tmp / "report.md").write_text(report(summary))
    progress(f"report in {out}/report.md")
    return summary


def main(config_path, out=None, *, workers: int | None = None, quiet: bool = False) -> int:
    """``clm-sim study CONFIG`` for a config with a ``mechanism:`` section."""
    run_checked(config_path, out, load_mechanism, run_mechanism, workers=workers,
                quiet=quiet)
    return 0