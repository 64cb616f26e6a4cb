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
