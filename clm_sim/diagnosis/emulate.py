"""Records measured on an emulated machine: the closed loop on a ``truth`` plant, with the PID
designed on the ``model`` plant (what the engineer believes) and dither for excitation."""

from __future__ import annotations

import numpy as np

from clm_sim.diagnosis.model import Controller, SimulationModel
from clm_sim.loop import Dither, simulate
from clm_sim.plant import Plant
from clm_sim.record import Run
from clm_sim.reference import PointToPoint
from controllers.pid import PIDDesign, design_pid

# The testbed's training reference r1: back and forth between -0.1 and 0.1 m.
R1 = PointToPoint(points_m=(0.0, 0.1, -0.1, 0.1, -0.1, 0.0), dwell_s=0.25)


def measure(truth: Plant, model: Plant, rng: np.random.Generator, *, ts: float = 1e-4,
            reference: PointToPoint = R1, repeats: int = 1, dither: Dither = Dither(),
            design: PIDDesign = PIDDesign()) -> tuple[Run, SimulationModel]:
    """A dithered closed-loop record on ``truth`` and the model that knows its controller."""
    pid = design_pid(mass=model.mass, viscous=model.viscous, stiffness=model.stiffness,
                     design=design, ts=ts)
    r = reference.sample(ts).r
    r = np.concatenate([np.tile(r[:-1], repeats), r[-1:]])
    run = simulate(truth, pid, r, ts, dither=dither.draw(len(r), rng),
                   meta={"source": "emulated machine"})
    controller = Controller(np.asarray(pid.b, float), np.asarray(pid.a, float), np.zeros(0))
    return run, SimulationModel(model, controller, "nominal")


def diagnose_emulated(*, model: Plant, truth: Plant, controller, features, record: Run,
                      references: dict[str, np.ndarray], out, name: str = "model",
                      progress=print) -> dict:
    """The truth-plant path of an experiment: diagnose ``model`` on ``record`` (measured on
    ``truth`` with ``controller``), write the report into ``out``, and measure the LIP
    feedforward's tracking MAE (m) on each reference, replayed on the truth, before and after
    adding the found effects to the LIP. Returns the numbers (also written to
    ``out/feedforward_gain.json``).
    """
    import json
    from pathlib import Path

    from clm_sim.diagnosis.diagnose import diagnose
    from clm_sim.diagnosis.extend import fit_lip
    from clm_sim.diagnosis.report import write
    from controllers.lip import LIPFeedforward

    ts = record.ts
    ctrl = Controller(np.asarray(controller.b, float), np.asarray(controller.a, float),
                      np.zeros(0))
    result = diagnose(record, SimulationModel(model, ctrl, name))
    for k, f in enumerate(result.findings, 1):
        progress(f"diagnosis {k}. {f['effect']}: " + ", ".join(
            f"{n} {v:.4g}" if isinstance(v, float) else f"{n} {v['model']:.4g} -> {v['data']:.4g}"
            for n, v in f["parameters"].items()))
    lips = {"before": LIPFeedforward(features=features).fit(y=record.y, u=record.u, ts=ts),
            "after": fit_lip(features, result.effects, record)}
    effects = lips["after"].effects
    mae = {}
    for when, lip in lips.items():
        for ref, r in references.items():
            run = simulate(truth, controller, r, ts, u_ff=lip.feedforward(r, ts))
            mae.setdefault(ref, {})[when] = float(np.mean(np.abs(run.e)))
    gain = {"lip_mae_m": mae, "lip_effects": [e.as_config() for e in effects],
            "residual_rms_before": result.gain["residual_rms_before"],
            "residual_rms_after": result.gain["residual_rms_after"]}
    result.info["feedforward_gain"] = gain
    write(result, Path(out))
    (Path(out) / "feedforward_gain.json").write_text(json.dumps(gain, indent=1))
    progress("diagnosis: LIP feedforward MAE " + ", ".join(
        f"{ref} {v['before'] * 1e6:.3f} -> {v['after'] * 1e6:.3f} µm" for ref, v in mae.items()))
    return gain
