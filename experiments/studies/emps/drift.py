"""Why a diagnosis-extended model simulates a test record worse than the training record.

The extended model's terms are taken apart three ways (``explain_drift``):

* **Determined?** Each coefficient of the diagnosis's joint fit on the training record with
  white-noise and Newey-West (autocorrelation-robust, :mod:`experiments.stats.hac`) standard errors,
  and its value fitted again on each of ``blocks`` contiguous blocks of the training record: the
  spread a standard error cannot show when the machine itself changes within a record.
* **Which term?** The extended model refitted without one term at a time (the same terms and
  nonlinear parameters otherwise), simulated open loop on the training record, and refitted on
  its estimation part and simulated on its held-out part (training side).
* **After the fact** (uses the test record's output: an explanation, never an input of a row or
  of a rule): the same terms fitted on the test record's force residual, and the extended model
  with one parameter or effect taken from that fit, simulated on the test record; the test
  RMSE of each leave-one-out model.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from clm_sim.plant import THETA_NAMES, Plant
from clm_sim.run import Run
from experiments.diagnosis.context import Step
from experiments.diagnosis.extend import extended_plant, joint_fit
from experiments.diagnosis.residual import DiagnosisSettings, Residual
from experiments.diagnosis.search import forward_select
from experiments.stats.hac import newey_west
from experiments.studies.emps.plateaus import to_markdown as steady_table


@dataclass(frozen=True)
class Coefficient:
    """One coefficient of the joint fit (units of its column: N, N·s/m, kg, N/m): on the whole
    training record with its white and Newey-West standard errors, per contiguous block, and
    (after the fact) on the test record."""

    name: str
    value: float
    std_white: float
    std_hac: float
    blocks: tuple[float, ...]
    test: float

    @property
    def block_spread(self) -> float:
        """Standard deviation of the block values over the square root of their count: the
        standard error of the whole-record value if the blocks were independent."""
        b = np.asarray(self.blocks)
        return float(b.std(ddof=1) / np.sqrt(len(b)))


@dataclass(frozen=True)
class Drift:
    """The three views of :func:`explain_drift`; RMSEs in m."""

    coefficients: tuple[Coefficient, ...]
    lag1_autocorr: float
    hac_lags: int
    ablation: tuple[tuple[str, float, float, float], ...]  # dropped, train, held out, test
    swaps: tuple[tuple[str, float], ...]  # taken from the test fit, test RMSE
    test_fitted_rmse_m: float  # all terms fitted on the test record, simulated on it
    traces: tuple = ()  # (label, Simulation) on the test record, for plot_drift
    # The training record's constant-speed friction per cycle (emps_plateaus), model-free.
    steady: tuple = ()

    def to_json(self) -> dict:
        return {"coefficients": [dataclasses.asdict(c) for c in self.coefficients],
                "lag1_autocorr": self.lag1_autocorr, "hac_lags": self.hac_lags,
                "ablation": [dict(zip(("dropped", "train_rmse_m", "held_out_rmse_m",
                                       "test_rmse_m_after_the_fact"), a))
                             for a in self.ablation],
                "swaps_after_the_fact": [{"taken_from_test_fit": s, "test_rmse_m": r}
                                         for s, r in self.swaps],
                "test_fitted_rmse_m": self.test_fitted_rmse_m,
                "steady_friction_per_cycle": [dataclasses.asdict(c) for c in self.steady]}

    def to_markdown(self, published_test_m: float) -> list[str]:
        mm = 1e3
        out = ["| coefficient | whole training record | ± white | ± Newey-West | "
               "per contiguous block | ± from the blocks | test record (after the fact) |",
               "|---|---|---|---|---|---|---|"]
        for c in self.coefficients:
            out.append(f"| {c.name} | {c.value:.4g} | {c.std_white:.2g} | {c.std_hac:.2g} | "
                       f"{', '.join(f'{b:.3g}' for b in c.blocks)} | {c.block_spread:.2g} | "
                       f"{c.test:.4g} |")
        if self.steady:
            out += ["", "The training record's friction on its constant-speed plateaus, per "
                    "cycle of its program (model-free; a line through each direction's "
                    "plateaus, mean force against measured speed):", "",
                    *steady_table(list(self.steady))]
        out += ["", f"Residual lag-1 autocorrelation at the fitted samples "
                f"{self.lag1_autocorr:.2f}; Newey-West with {self.hac_lags} lags.", "",
                "| extended model | training RMSE (mm) | held-out RMSE (mm) | "
                "test RMSE (mm, after the fact) |", "|---|---|---|---|"]
        for name, tr, ho, te in self.ablation:
            out.append(f"| {'all terms' if name is None else 'without ' + name} | "
                       f"{tr * mm:.2f} | {ho * mm:.2f} | {te * mm:.2f} |")
        out += ["", "| extended model with, from the test record's fit (after the fact) | "
                "test RMSE (mm) |", "|---|---|"]
        out += [f"| nothing | {self.ablation[0][3] * mm:.2f} |"]
        out += [f"| {s} | {r * mm:.2f} |" for s, r in self.swaps]
        out += [f"| everything (all terms fitted on the test record) | "
                f"{self.test_fitted_rmse_m * mm:.2f} |", "",
                f"The published model: {published_test_m * mm:.2f} mm on test."]
        return out


def _steps_on(res: Residual, steps: list[Step]) -> list[Step]:
    return [Step(s.term, s.term.columns(res), s.gain, s.folds_improved, s.p_value)
            for s in steps]


def _plant(res: Residual, base: Plant, steps: list[Step]) -> Plant:
    findings, correction, effects = joint_fit(res, _steps_on(res, steps))
    return extended_plant(base, correction, effects)


def _take(plant: Plant, source: Plant, what: str) -> Plant:
    """``plant`` with the parameter ``what`` (a theta name) or the effect of type ``what`` of
    ``source``."""
    if what in THETA_NAMES:
        return dataclasses.replace(plant, **{what: getattr(source, what)})
    new = {e.type: e for e in source.effects if e.type != "force_offset"}
    return dataclasses.replace(plant, effects=tuple(new.get(e.type, e) if e.type == what else e
                                                    for e in plant.effects))


def explain_drift(train: Run, test: Run, base: Plant, simulate, *, estimation: Run,
                  held_out: Run, blocks: int = 5,
                  settings: DiagnosisSettings = DiagnosisSettings()) -> Drift:
    """The diagnosis's terms on ``train`` (model ``base``) taken apart (module docstring);
    ``simulate(plant, run)`` is the benchmark's open-loop simulation
    (:class:`experiments.records.simulation.Simulation`)."""
    def rmse(plant, run):
        return simulate(plant, run).score.rmse

    res = Residual(train, base, settings)
    steps = list(forward_select(res).steps)
    names = [f"{s.term.effect}: {k}" for s in steps for k in s.term.keys]
    x = np.column_stack([s.cols for s in steps])
    nw = newey_west(x, res.z)
    per_block = []
    block = np.minimum(np.arange(len(res.z)) * blocks // len(res.z), blocks - 1)
    for b in range(blocks):
        per_block.append(np.linalg.lstsq(x[block == b], res.z[block == b], rcond=None)[0])
    res_test = Residual(test, base, settings)
    x_test = np.column_stack([s.cols for s in _steps_on(res_test, steps)])
    on_test = np.linalg.lstsq(x_test, res_test.z, rcond=None)[0]
    coefficients = tuple(
        Coefficient(n, float(nw.theta[i]), float(nw.std_white[i]),
                    float(nw.std_newey_west[i]),
                    tuple(float(c[i]) for c in per_block), float(on_test[i]))
        for i, n in enumerate(names))

    res_est = Residual(estimation, base, settings)
    ablation = []
    for drop in [None] + [s.term.effect for s in steps]:
        kept = [s for s in steps if s.term.effect != drop]
        whole, part = _plant(res, base, kept), _plant(res_est, base, kept)
        ablation.append((drop, rmse(whole, train), rmse(part, held_out), rmse(whole, test)))
    full = _plant(res, base, steps)
    fitted_on_test = _plant(res_test, base, steps)
    swaps = [(w, rmse(_take(full, fitted_on_test, w), test))
             for w in [*THETA_NAMES, *(e.type for e in full.effects
                                       if e.type != "force_offset")]]
    best = min(swaps, key=lambda s: s[1])[0]
    traces = (("extended model", simulate(full, test)),
              (f"with the test fit's {best}", simulate(_take(full, fitted_on_test, best), test)),
              ("all terms fitted on the test record", simulate(fitted_on_test, test)))
    return Drift(coefficients, float(nw.lag1_autocorr), int(nw.lags), tuple(ablation),
                 tuple(swaps), traces[2][1].score.rmse, traces)


def plot_drift(drift: Drift, ax=None):
    """The extended model's simulation error on the test record (mm against s), beside the same
    model with the one parameter or effect of the test fit that helps most, and with everything
    from the test fit (after the fact). Returns the axes."""
    from experiments import plots

    if ax is None:
        ax = plots._figure(10.0, 4.0).subplots()
    for i, (label, sim) in enumerate(drift.traces):
        ax.plot(sim.t, (sim.y_measured - sim.y_simulated) * 1e3, color=plots.PALETTE[i],
                lw=1.0, label=f"{label}: RMSE {sim.score.rmse * 1e3:.3g} mm")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("measured − simulated (mm)")
    plots._legend_right(ax)
    return ax
