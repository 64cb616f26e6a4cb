"""Integration sub-steps per sample: time of the closed loop against accuracy of the trajectory.

The loop of ``bench_loop.py`` (default plant and PID, r1 repeated to ``--samples``, dither on;
``--dither-std 0`` for none, as in a replay) is run with ``substeps`` = 2, 4, 8, 16 and 32. For
each: the best wall time of ``--repeats`` runs after a warm-up, and the largest difference of the
true position from the 32-sub-step run and from the run with twice as many sub-steps (the plant's
accuracy criterion: halving the sub-step must move the trajectory by less than one encoder count),
in metres and in encoder counts, and the share of samples whose encoder reading differs.
Prints a table on stdout. Run from the repository root: ``python benchmarks/bench_substeps.py``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from clm_sim.loop import Dither, simulate
from clm_sim.plant import Plant
from controllers.pid import PIDDesign, design_pid
from experiments.config import ExperimentConfig

from bench_loop import reference


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=400_000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0, help="seed of the dither")
    parser.add_argument("--dither-std", type=float, default=50.0, help="dither std, N (0: off)")
    args = parser.parse_args(argv)

    ts = ExperimentConfig().ts
    r = reference(args.samples, ts)
    d = Dither(std_n=args.dither_std).draw(args.samples, np.random.default_rng(args.seed))
    counts = (2, 4, 8, 16, 32)
    runs, times = {}, {}
    for n in counts:
        plant = Plant(substeps=n)
        pid = design_pid(mass=plant.mass, viscous=plant.viscous, stiffness=plant.stiffness,
                         design=PIDDesign(), ts=ts)
        runs[n] = simulate(plant, pid, r, ts, dither=d)
        best = np.inf
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            simulate(plant, pid, r, ts, dither=d)
            best = min(best, time.perf_counter() - t0)
        times[n] = best
    q = Plant().encoder_resolution
    print(f"{'substeps':>8} {'time_s':>8} {'max|x-x32|_m':>13} {'counts':>7} "
          f"{'max|x-x2n|_m':>13} {'counts':>7} {'y_differs':>9}")
    for n in counts:
        fine = np.max(np.abs(runs[n].y_true - runs[counts[-1]].y_true))
        line = f"{n:>8} {times[n]:>8.4f} {fine:>13.3g} {fine / q:>7.3f}"
        if 2 * n in runs:
            half = np.max(np.abs(runs[n].y_true - runs[2 * n].y_true))
            differs = np.mean(runs[n].y != runs[2 * n].y)
            line += f" {half:>13.3g} {half / q:>7.3f} {differs:>9.2%}"
        print(line)


if __name__ == "__main__":
    main()
