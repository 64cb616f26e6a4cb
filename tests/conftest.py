"""Shared fixtures: sample time, default PID, and the expensive closed-loop runs (once per session)."""

from __future__ import annotations

# Before numpy, scipy or torch load: the kernels the CLI pins (docs/reproducibility.md), so a test
# that runs the CLI in-process computes what `clm-sim` computes.
from clm_sim.numerics import pin_portable_kernels

pin_portable_kernels()

import numpy as np  # noqa: E402
import pytest

from clm_sim.loop import Dither, simulate
from clm_sim.plant import Plant
from controllers.pid import PIDDesign, design_pid
from experiments.config import ExperimentConfig

TS = 1e-4  # s: the 10 kHz sample time of the product


class ZeroController:
    """``C(z) = 0``: the loop is open and the plant sees only ``u_ff + dither``."""

    b = np.array([0.0])
    a = np.array([1.0])


@pytest.fixture(scope="session")
def ts() -> float:
    return TS


@pytest.fixture(scope="session")
def zero_controller() -> ZeroController:
    return ZeroController()


@pytest.fixture(scope="session")
def default_pid():
    """The default design (30 Hz crossover) for the default plant's linear part."""
    p = Plant()
    return design_pid(mass=p.mass, viscous=p.viscous, stiffness=p.stiffness, design=PIDDesign(),
                      ts=TS)


@pytest.fixture(scope="session")
def r1() -> np.ndarray:
    """One pass of the default training reference r1 (m), 17.6 s."""
    return ExperimentConfig().references["r1"].sample(TS).r


@pytest.fixture(scope="session")
def r1_dither(r1) -> np.ndarray:
    """The default 50 N dither for one pass of r1, from a fixed seed."""
    return Dither().draw(len(r1), np.random.default_rng(12345))


@pytest.fixture(scope="session")
def default_training_run(default_pid, r1, r1_dither):
    """The default plant in closed loop on one pass of r1 with dither."""
    return simulate(Plant(), default_pid, r1, TS, dither=r1_dither)
