"""The PGNN optimizer against the one it replaced, on the same fits (a benchmark, not a test).

Same data (the paper table's training run, filtered and decimated as the PGNN fits it), same cost
(the paper table's: n_l = 16, weight decay 1e-5, lambda = 0 and 0.01), same network draws, same
convergence test (the Gauss-Newton model predicts at most ``ftol`` relative decrease):

* ``varpro`` (new): output layer and theta_phy eliminated by least squares at every step,
  Levenberg-Marquardt on the hidden layer;
* ``lm`` (the method on main before): Levenberg-Marquardt on all parameters, started from the
  same lemma initialization.

Per fit it prints CPU time, iterations, how it stopped and the final training cost; then per
lambda the median CPU-time ratio lm / varpro, the mean final-cost ratio and how many converged.
Times are CPU (process) time, the fair figure on a shared machine; every fit runs on one thread.

    python benchmarks/bench_optimizer.py [--seeds 5] [--max-iter 200] [--lm-iter 200]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from controllers.pgnn import PGNNFeedforward, training_data
from controllers.pgnn_settings import PGNNSettings
from experiments.testbed import STREAM_NETWORK, Testbed, stream

ROOT = Path(__file__).resolve().parents[1]


def fit(data, theta_lip, seq, **settings):
    c0 = time.process_time()
    model = PGNNFeedforward(**settings).fit_data(data=data, theta_lip=theta_lip,
                                                 rng=np.random.default_rng(seq))
    f = model.fit_
    return {"cpu_s": time.process_time() - c0, "stop": f.stop, "iterations": f.iterations,
            "cost": f.data_cost + f.reg_cost}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--max-iter", type=int, default=200, help="cap of both optimizers")
    ap.add_argument("--hidden", type=int, default=16)
    ap.add_argument("--weight-decay", type=float, default=1e-5)
    args = ap.parse_args(argv)

    tb = Testbed.from_config(ROOT / "experiments/configs/paper_table.yaml")
    run = tb.training_run()
    lip = tb.fit_lip(run)
    base = {"hidden": args.hidden, "weight_decay": args.weight_decay, "max_iter": args.max_iter}
    data = training_data(tb.config.features, y=run.y, u=run.u, ts=run.ts,
                         decimation=PGNNSettings().decimation)
    print(f"data: {len(data.target)} samples; n_l = {args.hidden}, weight decay "
          f"{args.weight_decay:g}, cap {args.max_iter} iterations, ftol "
          f"{PGNNSettings().ftol:g}; CPU seconds per fit")
    for lam in (0.0, 0.01):
        res = {"varpro": [], "lm": []}
        for s in range(args.seeds):
            seq = stream(tb.config.seed, STREAM_NETWORK, s)
            for opt, got in res.items():
                r = fit(data, lip.theta_, seq, lam=lam, optimizer=opt, **base)
                got.append(r)
                print(f"lambda={lam:<5g} seed {s} {opt:6s}: {r['cpu_s']:6.2f} s CPU, "
                      f"{r['iterations']:4d} iterations, {r['stop']:9s} cost {r['cost']:.6f} N²",
                      flush=True)
        t = {k: np.array([r["cpu_s"] for r in v]) for k, v in res.items()}
        c = {k: np.array([r["cost"] for r in v]) for k, v in res.items()}
        conv = {k: sum(r["stop"] == "converged" for r in v) for k, v in res.items()}
        print(f"lambda={lam:g}: converged varpro {conv['varpro']}/{args.seeds}, lm "
              f"{conv['lm']}/{args.seeds}; median CPU time varpro {np.median(t['varpro']):.2f} s, "
              f"lm {np.median(t['lm']):.2f} s, ratio lm/varpro "
              f"{np.median(t['lm']) / np.median(t['varpro']):.1f}; mean final cost varpro "
              f"{c['varpro'].mean():.6f}, lm {c['lm'].mean():.6f} N², ratio lm/varpro "
              f"{c['lm'].mean() / c['varpro'].mean():.4f}", flush=True)


if __name__ == "__main__":
    main()
