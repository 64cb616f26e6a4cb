"""CPU time of one open-loop simulation of a record (the unit of a simulation-error fit).

Each model file given (default: the EMPS page's published model, its chosen model and the fit
with the diagnosis's terms, which has pre-sliding friction) is simulated open loop from the
record's input (``clm_sim.open_loop``, as one residual evaluation of
``experiments.records.output_error.fit``); printed: the best CPU time of ``--repeats`` runs after a
warm-up, per run and per sample. ``--save FILE`` stores the simulated positions (``.npz``),
``--check FILE`` prints the largest difference from stored ones (m, and relative to the
position's range) and whether they are bit-identical; with them, the closed loop of the default
experiment (default plant and PID, reference r1, 200 000 samples with dither: the paper
table's loop) without and with pre-sliding friction, whose encoder positions are compared the
same way (a change of the pre-sliding solver must leave the first bit-identical). Run from the
repository root::

    python benchmarks/bench_open_loop.py --save /tmp/before.npz
    python benchmarks/bench_open_loop.py --check /tmp/before.npz
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from clm_sim.effects import Presliding
from clm_sim.loop import Dither, simulate
from clm_sim.open_loop import initial_state, simulate_input
from clm_sim.plant import Plant
from clm_sim.records.read import load_record
from controllers.pid import PIDDesign, design_pid
from experiments.config import ExperimentConfig
from experiments.model_files import load_model

MODELS = ("published_model", "asymmetric_viscous_friction", "the_diagnosis_s_terms")
CLOSED_LOOP = {"closed loop, default plant": Plant(),
               "closed loop, pre-sliding": Plant(effects=(Presliding(sliding=4.0,
                                                                     stiffness=2.0e5),))}


def _compare(name, x, stored) -> str:
    if name not in stored:
        return ""
    ok = np.isfinite(x)
    diff = float(np.max(np.abs(x[ok] - stored[name][ok])))
    same = np.array_equal(x[ok], stored[name][ok])
    return (f"  max |diff| {diff:.3g} m ({diff / np.ptp(x[ok]):.2g} of the range)"
            f"{', bit-identical' if same else ''}")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--record", default="../shared/data/emps/DATA_EMPS.mat")
    parser.add_argument("--models", nargs="*",
                        default=[f"docs/results/emps_models/{m}.json" for m in MODELS])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--save")
    parser.add_argument("--check")
    args = parser.parse_args(argv)

    run = load_record(args.record, columns={"y": "qm", "r": "qg", "u": "vir"},
                      scale={"u": "gtau"})
    stored = dict(np.load(args.check)) if args.check else {}
    out = {}
    print(f"{args.record}: {len(run)} samples; best CPU time of {args.repeats} runs (closed "
          f"loop: one run)")
    for path in args.models:
        plant = load_model(path, ts=run.ts).plant
        state = initial_state(run.y, run.ts, plant)
        x, _ = simulate_input(plant, run.u, run.ts, state)  # warm-up (compilation)
        best = np.inf
        for _ in range(args.repeats):
            t0 = time.process_time()
            x, _ = simulate_input(plant, run.u, run.ts, state)
            best = min(best, time.process_time() - t0)
        name = Path(path).stem
        out[name] = x
        print(f"{name:32s} {best * 1e3:9.2f} ms per run  {best / len(run) * 1e9:8.1f} ns per "
              f"sample" + _compare(name, x, stored))
    ts = ExperimentConfig().ts
    r = ExperimentConfig().references["r1"].sample(ts).r
    r = np.tile(r[:-1], -(-200_000 // (len(r) - 1)))[:200_000]
    d = Dither(std_n=50.0).draw(len(r), np.random.default_rng(0))
    for name, plant in CLOSED_LOOP.items():
        pid = design_pid(mass=plant.mass, viscous=plant.viscous, stiffness=plant.stiffness,
                         design=PIDDesign(), ts=ts)
        simulate(plant, pid, r[:100], ts, dither=d[:100])  # warm-up (compilation)
        t0 = time.process_time()
        y = simulate(plant, pid, r, ts, dither=d).y
        cpu = time.process_time() - t0
        out[name] = y
        print(f"{name:32s} {cpu * 1e3:9.2f} ms per run  {cpu / len(r) * 1e9:8.1f} ns per "
              f"sample" + _compare(name, y, stored))
    if args.save:
        np.savez(args.save, **out)


if __name__ == "__main__":
    main()
