"""Records measured on an emulated machine: the testbed's closed loop on a ``truth`` plant, with
the PID designed on the ``model`` plant (what the engineer believes) and dither for excitation."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from clm_sim.loop import Dither
from clm_sim.plant import Plant
from clm_sim.run import Run
from controllers.lip import LIPFeedforward
from controllers.pid import PIDDesign
from experiments.config import ExperimentConfig, Training
from experiments.diagnosis.diagnose import diagnose
from experiments.diagnosis.extend import fit_lip
from experiments.diagnosis.outcome import FeedforwardGain
from experiments.diagnosis.report import write
from experiments.model_files import Controller, SimulationModel
from experiments.testbed import Testbed


def measure(truth: Plant, model: Plant, seed: int, *, ts: float = 1e-4, repeats: int = 1,
            dither: Dither = Dither(), design: PIDDesign = PIDDesign()
            ) -> tuple[Run, SimulationModel]:
    """A dithered closed-loop record on ``truth`` (the testbed's training run on r1) and the
    model that knows its controller."""
    config = ExperimentConfig(ts=ts, plant=model, truth=truth, controller=design,
                              training=Training(repeats=repeats, dither=dither))
    tb = Testbed(config)
    run = tb.training_run(seed)
    run.meta["source"] = "emulated machine"
    return run, simulation_model(tb)


def simulation_model(tb: Testbed, name: str = "nominal") -> SimulationModel:
    """The testbed's model plant and PID as a diagnosis model."""
    ctrl = Controller(np.asarray(tb.pid.b, float), np.asarray(tb.pid.a, float), np.zeros(0),
                      tb.ts)
    return SimulationModel(tb.plant, ctrl, name, tb.ts)


def diagnose_emulated(tb: Testbed, *, record: Run, out, progress=print) -> dict:
    """The truth-plant path of an experiment: diagnose the testbed's model plant on ``record``
    (measured on its truth), write the report into ``out``, and measure the LIP feedforward's
    tracking MAE (m) on each replay reference, replayed on the truth, before and after adding
    the found effects to the LIP. Returns the numbers (also written to
    ``out/feedforward_gain.json``).
    """
    result = diagnose(record, simulation_model(tb, tb.config.name))
    for line in result.summary().splitlines():
        progress(f"diagnosis: {line}")
    features = tb.config.features
    lips = {"before": LIPFeedforward(features=features).fit(y=record.y, u=record.u, ts=tb.ts),
            "after": fit_lip(features, result.effects, record)}
    effects = lips["after"].effects
    mae = {}
    for when, lip in lips.items():
        for ref in tb.config.replay:
            mae.setdefault(ref, {})[when] = tb.replay(lip, ref).mae
    ff = FeedforwardGain(lip_mae_m=mae, lip_effects=tuple(e.as_config() for e in effects),
                         residual_rms_before=result.gain.residual_rms_before,
                         residual_rms_after=result.gain.residual_rms_after)
    result.info = dataclasses.replace(result.info, feedforward_gain=ff)
    gain = ff.to_json()
    write(result, Path(out))
    (Path(out) / "feedforward_gain.json").write_text(json.dumps(gain, indent=1))
    progress("diagnosis: LIP feedforward MAE " + ", ".join(
        f"{ref} {v['before'] * 1e6:.3f} -> {v['after'] * 1e6:.3f} µm" for ref, v in mae.items()))
    return gain
