"""Levenberg-Marquardt against full-batch Adam for the PGNN fit (a benchmark, not a test).

Same data (the default training run, filtered and decimated as the PGNN fits it), same cost
(regularized, lambda = 0.01, n_l = 16), same random initialization (``init: random``). Prints the
time each optimizer needs to come within 0.1 % of the best cost either of them found, and the
ratio. Times are wall clock and CPU (process) time; the CPU time is the fairer figure on a shared
machine. Adam runs for a fixed budget per learning rate; when it never comes within 0.1 % the
ratio printed is a lower bound.

    python benchmarks/bench_optimizer.py [--hidden 16] [--lm-iter 200] [--adam-seconds 120]

``--sensitivity`` instead prints how the replayed MAE on r1 and r2 and the CPU time of one fit
depend on the LM iteration cap and on the decimation of the training data (3 seeds each), which
is how the defaults (100 iterations, decimation 20) were chosen.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from clm_sim.loop import simulate
from controllers import optim
from controllers.pgnn import PGNNFeedforward, training_data
from experiments.config import ExperimentConfig
from experiments.testbed import Testbed


class Clock:
    """Cost against wall and CPU time, recorded by the optimizer's callback."""

    def __init__(self):
        self.t0, self.c0 = time.perf_counter(), time.process_time()
        self.trace = []

    def __call__(self, cost):
        self.trace.append((time.perf_counter() - self.t0, time.process_time() - self.c0, cost))

    def reach(self, target):
        for wall, cpu, cost in self.trace:
            if cost <= target:
                return wall, cpu
        return None


def run(model, data, theta_lip, seed, deadline_s=None):
    """Optimize ``model``'s training cost from its initialization; the cost trace against time."""
    problem, p0 = model.training_problem(data, theta_lip, np.random.default_rng(seed))
    clock = Clock()

    class Stop(Exception):
        pass

    def callback(it, p, cost):
        clock(cost)
        if deadline_s is not None and clock.trace[-1][0] > deadline_s:
            raise Stop

    with optim.blas_threads(1):
        try:
            if model.optimizer == "lm":
                optim.levenberg_marquardt(problem, p0, max_iter=model.max_iter, callback=callback)
            else:
                optim.adam(problem, p0, max_iter=model.max_iter, lr=model.adam_lr,
                           callback=callback)
        except Stop:
            pass
    return clock


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hidden", type=int, default=16)
    ap.add_argument("--lam", type=float, default=0.01)
    ap.add_argument("--lm-iter", type=int, default=200)
    ap.add_argument("--adam-seconds", type=float, default=120.0)
    ap.add_argument("--adam-lr", type=float, nargs="+", default=[1e-3, 1e-2])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--sensitivity", action="store_true")
    args = ap.parse_args(argv)

    config = ExperimentConfig(seed=1)
    tb = Testbed(config)
    ts, pid = config.ts, tb.pid
    train = tb.training_run()
    lip = tb.fit_lip(train)
    if args.sensitivity:
        return sensitivity(config, pid, train, lip, args.hidden)
    data = training_data(config.features, y=train.y, u=train.u, ts=ts)
    print(f"data: {len(data.target)} samples, n_l = {args.hidden}, lambda = {args.lam:g}, "
          f"init random (seed {args.seed})")

    clocks = {"LM": run(PGNNFeedforward(hidden=args.hidden, lam=args.lam, init="random",
                                        max_iter=args.lm_iter), data, lip.theta_, args.seed)}
    for lr in args.adam_lr:
        model = PGNNFeedforward(hidden=args.hidden, lam=args.lam, init="random",
                                optimizer="adam", adam_lr=lr, max_iter=10**9)
        clocks[f"Adam lr={lr:g}"] = run(model, data, lip.theta_, args.seed,
                                        deadline_s=args.adam_seconds)
    best = min(c for clock in clocks.values() for _, _, c in clock.trace)
    target = best * 1.001
    print(f"best cost found {best:.6g} N²; target (within 0.1 %) {target:.6g} N²")
    reached = {}
    for name, clock in clocks.items():
        got = clock.reach(target)
        final = min(c for _, _, c in clock.trace)
        steps = len(clock.trace) - 1
        total_wall, total_cpu = clock.trace[-1][0], clock.trace[-1][1]
        if got is None:
            print(f"{name:14s} not within 0.1 % after {total_wall:.1f} s wall / {total_cpu:.1f} s "
                  f"CPU ({steps} steps; best {final:.6g} N², {100 * (final / best - 1):.2f} % "
                  f"above)")
            reached[name] = (None, total_wall, total_cpu)
        else:
            print(f"{name:14s} within 0.1 % after {got[0]:.2f} s wall / {got[1]:.2f} s CPU "
                  f"({steps} steps run in all)")
            reached[name] = (got, total_wall, total_cpu)
    lm = reached["LM"][0]
    for name, (got, wall, cpu) in reached.items():
        if name == "LM" or lm is None:
            continue
        if got is None:
            print(f"ratio {name} / LM > {wall / lm[0]:.0f} (wall), > {cpu / lm[1]:.0f} (CPU)")
        else:
            print(f"ratio {name} / LM = {got[0] / lm[0]:.1f} (wall), {got[1] / lm[1]:.1f} (CPU)")


def sensitivity(config, pid, train, lip, hidden, seeds=3):
    """MAE (mean ± std over seeds) and CPU time per fit against iterations and decimation."""
    ts, plant = config.ts, config.plant
    refs = {k: config.references[k].sample(ts).r for k in ("r1", "r2")}
    print(f"n_l = {hidden}, {seeds} seeds; MAE in um (mean ± std), CPU s per fit")
    for lam in (0.0, 0.01):
        for decimation in (10, 20, 40):
            data = training_data(config.features, y=train.y, u=train.u, ts=ts,
                                 decimation=decimation)
            for max_iter in (30, 100, 200):
                maes, cpu = {k: [] for k in refs}, []
                for seed in range(seeds):
                    c0 = time.process_time()
                    model = PGNNFeedforward(hidden=hidden, lam=lam, max_iter=max_iter,
                                            decimation=decimation).fit_data(
                        data=data, theta_lip=lip.theta_, rng=np.random.default_rng(seed))
                    cpu.append(time.process_time() - c0)
                    for k, r in refs.items():
                        run = simulate(plant, pid, r, ts, u_ff=model.feedforward(r, ts))
                        maes[k].append(np.mean(np.abs(run.e)) * 1e6)
                print(f"lambda={lam:<5g} decimation={decimation:3d} ({len(data.target):6d} "
                      f"samples) max_iter={max_iter:4d}: " + ", ".join(
                          f"{k} {np.mean(v):.3f} ± {np.std(v, ddof=1):.3f}"
                          for k, v in maes.items()) + f"; {np.mean(cpu):.1f} s CPU", flush=True)


if __name__ == "__main__":
    main()
