"""Speed of the product's 10 kHz closed loop against the same loop built from python-control.

The loop: the default plant (default parasitic effects, default encoder), the default PID from
``design_pid``, reference r1 repeated and cut to ``--samples`` samples, Gaussian dither on the
plant input. The product runs it with :func:`clm_sim.loop.simulate` (timed after a warm-up call,
best of ``--repeats``). python-control runs the identical loop: the plant is a discrete-time
``NonlinearIOSystem`` whose update is the pure-Python twin of the compiled plant step and whose
output is the encoder reading; the PID is ``pid.discrete`` (python-control's discretized transfer
function); summing junctions close the loop; ``input_output_response`` simulates it. It is slow,
so it runs the first ``--oracle-samples`` samples and its time is scaled linearly to
``--samples``. The true positions of the two must agree to 1e-9 m on that horizon.

Prints details on stderr and, last, one line on stdout:
``speedup_vs_python_control=<ratio> max_abs_diff_m=<d> product_s=<t>``. Exit code 1 if the
trajectories disagree. Run from the repository root: ``python benchmarks/bench_loop.py``.
"""

from __future__ import annotations

import argparse
import sys
import time
import types

import control as ct
import numpy as np

from clm_sim import kernel
from clm_sim.loop import Dither, simulate
from clm_sim.plant import Plant
from controllers.pid import PIDDesign, design_pid
from experiments.config import ExperimentConfig

AGREEMENT_M = 1e-9  # the agreement asked of the loop: 1 % of an encoder count


def python_twin(dispatcher):
    """The pure-Python function behind a numba dispatcher, with every compiled helper it calls
    replaced by that helper's own pure-Python twin, so that no compiled code runs in the oracle."""
    f = dispatcher.py_func
    scope = dict(f.__globals__)
    for name in f.__code__.co_names:
        if hasattr(scope.get(name), "py_func"):
            scope[name] = python_twin(scope[name])
    return types.FunctionType(f.__code__, scope, f.__name__, f.__defaults__, f.__closure__)


def reference(n: int, ts: float) -> np.ndarray:
    """Reference r1 (m) of the default experiment, repeated end to start and cut to ``n``."""
    r = ExperimentConfig().references["r1"].sample(ts).r
    return np.tile(r[:-1], -(-n // (len(r) - 1)))[:n]


def python_control_loop(plant: Plant, pid, ts: float):
    """The closed loop as a python-control interconnection with inputs ``r``, ``d`` (dither) and
    outputs ``y`` (encoder), ``u`` (plant input); states ``[x, v, controller states]``."""
    step = python_twin(kernel.plant_step)
    terms = plant.kernel_plant(ts)
    q = plant.encoder_resolution

    def update(t, state, u, params):
        return np.array(step(state[0], state[1], u[0], terms))

    def output(t, state, u, params):
        x = state[0]
        return np.array([x if q == 0.0 else q * np.floor(x / q + 0.5)])

    motor = ct.NonlinearIOSystem(update, output, inputs=["u"], outputs=["y"],
                                 states=["x", "v"], dt=ts, name="motor")
    controller = ct.ss(pid.discrete, inputs="e", outputs="u_fb", name="pid")
    error = ct.summing_junction(inputs=["r", "-y"], output="e", name="error")
    force = ct.summing_junction(inputs=["u_fb", "d"], output="u", name="force")
    return ct.interconnect([motor, controller, error, force], inputs=["r", "d"],
                           outputs=["y", "u"], dt=ts, name="clm")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=400_000)
    parser.add_argument("--oracle-samples", type=int, default=20_000)
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--seed", type=int, default=0, help="seed of the dither")
    parser.add_argument("--substeps", type=int, default=None,
                        help="plant integration sub-steps (default: the plant's default)")
    args = parser.parse_args(argv)

    def note(text):
        print(text, file=sys.stderr, flush=True)

    ts = ExperimentConfig().ts
    plant = Plant() if args.substeps is None else Plant(substeps=args.substeps)
    pid = design_pid(mass=plant.mass, viscous=plant.viscous, stiffness=plant.stiffness,
                     design=PIDDesign(), ts=ts)
    n, m = args.samples, min(args.oracle_samples, args.samples)
    r = reference(n, ts)
    d = Dither().draw(n, np.random.default_rng(args.seed))

    t0 = time.perf_counter()
    run = simulate(plant, pid, r, ts, dither=d)
    note(f"product: first call {time.perf_counter() - t0:.2f} s (compilation or cache load)")
    times, cpu = [], []
    for _ in range(args.repeats):
        t0, c0 = time.perf_counter(), time.thread_time()
        simulate(plant, pid, r, ts, dither=d)
        times.append(time.perf_counter() - t0)
        cpu.append(time.thread_time() - c0)
    product_s = min(times)
    note(f"product: {n} samples, best {product_s:.4f} s of "
         f"{' '.join(f'{t:.4f}' for t in times)} ({product_s / n * 1e9:.0f} ns/sample); "
         f"best CPU time {min(cpu):.4f} s (what a loaded machine inflates less)")

    loop = python_control_loop(plant, pid, ts)
    x0 = np.zeros(loop.nstates)
    x0[0] = r[0]
    t0 = time.perf_counter()
    resp = ct.input_output_response(loop, np.arange(m) * ts, np.vstack([r[:m], d[:m]]), x0,
                                    return_states=True)
    oracle_s = time.perf_counter() - t0
    oracle_full_s = oracle_s * n / m
    note(f"python-control: {m} samples in {oracle_s:.2f} s, {oracle_full_s:.1f} s scaled to {n}")

    diff = float(np.max(np.abs(resp.states[0] - run.y_true[:m])))
    counts = int(np.sum(resp.outputs[0] != run.y[:m]))
    du = float(np.max(np.abs(resp.outputs[1] - run.u[:m])))
    note(f"agreement over {m} samples: max |x difference| {diff:.3g} m (bar {AGREEMENT_M:g} m), "
         f"encoder readings differing: {counts}, max |u difference| {du:.3g} N")

    print(f"speedup_vs_python_control={oracle_full_s / product_s:.0f} "
          f"max_abs_diff_m={diff:.3g} product_s={product_s:.4f}")
    return 0 if diff <= AGREEMENT_M else 1


if __name__ == "__main__":
    sys.exit(main())
