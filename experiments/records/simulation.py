"""A model's forward simulation against a measured record (``clm-sim simulate MODEL RECORD``,
:mod:`experiments.cli.simulate`).

    model file (identify's lip.json, a diagnosis.json's extended plant, a model YAML)
    + record -> open loop from the record's input, initial state from its first output samples
    (clm_sim.open_loop) -> simulated beside measured (CSV, NPZ), figure, scores

The model owns its sample time (a lip.json's ``ts``, a model file's ``ts`` or its controller's,
a diagnosis's record): a record sampled at another rate is refused; a file that gives none (an
experiment config without ``ts:``) runs at the record's, as in ``diagnose``. Models without a forward
form (a PGNN: an inverse model whose network has no plant) are refused by name.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from clm_sim.errors import UserError, check_ts
from clm_sim.open_loop import (INIT_SAMPLES, MIN_SCORED_SAMPLES, Score, initial_state, score,
                               simulate_input)
from clm_sim.outdir import atomic_folder
from clm_sim.plant import Plant
from experiments.model_files import SimulationModel
from clm_sim.run import Run

COLUMNS = ("t", "u", "y_measured", "y_simulated", "error")


@dataclass(frozen=True)
class Simulation:
    """A model simulated against a record: the measured and simulated position (m) per sample,
    the input (N), the window the initial state came from, and the :class:`Score` after it."""

    model: str
    record: str
    t: np.ndarray
    u: np.ndarray
    y_measured: np.ndarray
    y_simulated: np.ndarray
    init_samples: int
    score: Score
    plant: Plant

    def __repr__(self) -> str:
        return (f"Simulation({self.model!r} on {self.record!r}: RMSE "
                f"{self.score.rmse * 1e3:.4g} mm)")

    def columns(self) -> dict[str, np.ndarray]:
        """The named columns written to CSV and NPZ (SI units; ``error = y_measured -
        y_simulated``; NaN inside the initialization window)."""
        return {"t": self.t, "u": self.u, "y_measured": self.y_measured,
                "y_simulated": self.y_simulated, "error": self.y_measured - self.y_simulated}

    def summary(self) -> str:
        s = self.score
        return (f"{self.model} on {self.record}, open loop from the input, initial state from "
                f"the first {self.init_samples} output samples:\n"
                f"position: RMSE {s.rmse * 1e3:.4g} mm, {s.ratios()}, "
                f"max |error| {s.max_abs * 1e3:.4g} mm over the "
                f"{s.samples} samples after the window")

    def to_json(self) -> dict:
        return {"model": self.model, "record": self.record, "mode": "open loop",
                "init_samples": self.init_samples,
                "sample_time_s": float((self.t[-1] - self.t[0]) / (len(self.t) - 1)),
                "position": {**self.score.as_dict(), "unit": "m"},
                "plant": {**self.plant.theta(),
                          "effects": [e.as_config() for e in self.plant.effects],
                          "substeps": self.plant.substeps}}


def simulate_record(model: SimulationModel, run: Run, *, init_samples: int = INIT_SAMPLES,
                    source: str | None = None, substeps: int | None = None) -> Simulation:
    """``model``'s plant driven by ``run.u`` (N) open loop, its initial state from
    ``run.y[:init_samples]`` only, scored after them. ``substeps`` overrides the plant's."""
    source = source or str(run.meta.get("source", "record"))
    check_ts(model.ts, run.ts, f"{source}: the model ({model.name})")
    plant = model.plant if substeps is None else dataclasses.replace(model.plant,
                                                                     substeps=substeps)
    scored = len(run.y) - init_samples if isinstance(init_samples, int) else None
    if scored is not None and 0 < init_samples and scored < MIN_SCORED_SAMPLES:
        raise UserError(f"{source}: {init_samples} initialization samples (--init-samples, a "
                        f"benchmark's init_samples) leave {max(scored, 0)} of the record's "
                        f"{len(run.y)} samples to score; at least {MIN_SCORED_SAMPLES} are "
                        f"needed (fewer initialization samples or a longer record)")
    state = initial_state(run.y, run.ts, plant, init_samples)
    try:
        x, _ = simulate_input(plant, run.u, run.ts, state)
    except UserError as exc:
        raise UserError(f"{source}: {exc}") from None
    return Simulation(model.name, source, run.t, run.u, run.y, x, init_samples,
                      score(run.y, x, init_samples), plant)


@dataclass(frozen=True)
class Twin:
    """The machine's twin: the model's plant under the model file's controller on the record's
    reference (and the record's known external input: its ``u_ff`` and ``dither`` where given),
    from rest at the first reference sample. Predicts the position (m) and the input (N)."""

    model: str
    record: str
    t: np.ndarray
    r: np.ndarray
    y_measured: np.ndarray
    y_simulated: np.ndarray
    u_measured: np.ndarray
    u_simulated: np.ndarray
    position: Score
    input: Score

    def columns(self) -> dict[str, np.ndarray]:
        return {"t": self.t, "r": self.r, "y_measured": self.y_measured,
                "y_simulated": self.y_simulated, "u_measured": self.u_measured,
                "u_simulated": self.u_simulated}

    def summary(self) -> str:
        p, u = self.position, self.input
        return (f"{self.model} on {self.record}, closed loop (the model's controller on the "
                f"record's reference):\n"
                f"position: RMSE {p.rmse * 1e6:.4g} um, {p.ratios()}\n"
                f"input: RMSE {u.rmse:.4g} N, {u.ratios()}")

    def to_json(self) -> dict:
        return {"model": self.model, "record": self.record, "mode": "closed loop",
                "position": {**self.position.as_dict(), "unit": "m"},
                "input": {**self.input.as_dict(), "unit": "N"}}


def twin_record(model: SimulationModel, run: Run, *, source: str | None = None) -> Twin:
    """Re-run the machine: ``model``'s plant and controller on ``run.r``, with the record's
    known external input (``u_ff + dither`` where finite, else none); scored over all samples
    (the twin takes nothing from the measured output)."""
    from clm_sim.loop import simulate

    source = source or str(run.meta.get("source", "record"))
    ctrl = model.controller
    if ctrl is None:
        raise UserError(f"{model.name}: the model has no controller; the closed-loop twin needs "
                        f"one ('controller:' in a model YAML)")
    check_ts(ctrl.ts, run.ts, f"{source}: the model's controller ({model.name})")
    known = np.nan_to_num(run.u_ff, nan=0.0) + np.nan_to_num(run.dither, nan=0.0)
    try:
        sim = simulate(model.plant, ctrl, run.r, run.ts,
                       u_ff=known + ctrl.reference_force(run.r))
    except UserError as exc:
        raise UserError(f"{source}: {exc}") from None
    return Twin(model.name, source, run.t, run.r, run.y, sim.y, run.u, sim.u,
                score(run.y, sim.y, 0), score(run.u, sim.u, 0))


def write_twin(twin: Twin, out: Path) -> None:
    """``out/twin.csv`` and ``.npz`` (named columns), ``scores.json``, ``figures/twin.png``."""
    from experiments import plots

    with atomic_folder(out, what="a simulation") as tmp:
        cols = twin.columns()
        np.savetxt(tmp / "twin.csv", np.column_stack(list(cols.values())), delimiter=",",
                   header=",".join(cols), comments="", fmt="%.17g")
        with open(tmp / "twin.npz", "wb") as fh:
            np.savez_compressed(fh, **cols)
        (tmp / "scores.json").write_text(json.dumps(twin.to_json(), indent=1))
        fig = plots._figure(10.0, 6.0)
        top, bottom = fig.subplots(2, 1, sharex=True)
        top.plot(twin.t, (twin.y_measured - twin.r) * 1e6, color=plots.PALETTE[0], lw=1.0,
                 label="measured")
        top.plot(twin.t, (twin.y_simulated - twin.r) * 1e6, color=plots.PALETTE[1], lw=1.0,
                 ls="--", label="twin")
        top.set_ylabel("y − r (µm)")
        plots._legend_right(top)
        bottom.plot(twin.t, twin.u_measured, color=plots.PALETTE[0], lw=1.0, label="measured")
        bottom.plot(twin.t, twin.u_simulated, color=plots.PALETTE[1], lw=1.0, ls="--",
                    label="twin")
        bottom.set_ylabel("input (N)")
        bottom.set_xlabel("time (s)")
        plots.save(fig, tmp / "figures" / "twin.png")


def plot_simulation(sim: Simulation, axes=None):
    """Measured and simulated position (top) and their difference (bottom), in mm against
    time in s; the initialization window shaded. Returns the two axes."""
    from experiments import plots

    if axes is None:
        fig = plots._figure(10.0, 6.0)
        axes = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [2, 1]})
    top, bottom = axes
    t0 = sim.t[sim.init_samples]
    top.plot(sim.t, sim.y_measured * 1e3, color=plots.PALETTE[0], lw=1.0, label="measured")
    top.plot(sim.t, sim.y_simulated * 1e3, color=plots.PALETTE[1], lw=1.0, ls="--",
             label="simulated")
    top.set_ylabel("position (mm)")
    plots._legend_right(top)
    bottom.plot(sim.t, (sim.y_measured - sim.y_simulated) * 1e3, color=plots.PALETTE[3], lw=1.0)
    bottom.set_ylabel("measured − simulated (mm)")
    bottom.set_xlabel("time (s)")
    for ax in axes:
        ax.axvspan(sim.t[0], t0, color="0.85", lw=0)
    top.set_title(f"{sim.model}: RMSE {sim.score.rmse * 1e3:.4g} mm after the first "
                  f"{sim.init_samples} samples", fontsize=9)
    return axes


def write(sim: Simulation, out: Path) -> None:
    """``out/simulation.csv`` and ``.npz`` (the named columns), ``scores.json`` and
    ``figures/simulation.png``; the folder appears whole or not at all."""
    from experiments import plots

    with atomic_folder(out, what="a simulation") as tmp:
        cols = sim.columns()
        np.savetxt(tmp / "simulation.csv", np.column_stack([cols[k] for k in COLUMNS]),
                   delimiter=",", header=",".join(COLUMNS), comments="", fmt="%.17g")
        with open(tmp / "simulation.npz", "wb") as fh:
            np.savez_compressed(fh, **cols)
        (tmp / "scores.json").write_text(json.dumps(sim.to_json(), indent=1))
        axes = plot_simulation(sim)
        plots.save(axes[0].figure, tmp / "figures" / "simulation.png")
