"""Why a profile point does not pass the optimizer's convergence test (a diagnostic, not a test).

The profiles study's start (``experiments/configs/identifiability.yaml``, its first record, one
network size): the record's fit as the study runs it, then one pinned point ``steps`` scales
from theta*_k, run ``iters`` Levenberg-Marquardt iterations with no convergence stop. Every
``every`` iterations it prints the data cost (N**2), the first-order measure (the relative
decrease the Gauss-Newton model predicts), that decrease in N**2 and in units of delta (the
shipped study's, given with ``--delta``), the fall over the last 10 iterations; at the end the
damping mu, and how the predicted decrease splits over the eigen-directions of the scaled
Gauss-Newton matrix (the share carried by directions whose curvature is below a fraction of the
largest). CPU time is process time (a shared machine).

    python benchmarks/profile_point.py [--hidden 16] [--name mass] [--steps 0.25]
        [--iters 1000] [--every 100] [--delta 0.00851]
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    import torch

    from clm_sim.numerics import single_threaded
    from clm_sim.plant import THETA_NAMES
    from controllers import optim
    from controllers.pgnn import PGNNFeedforward
    from controllers.pgnn.cost import SeparableCost
    from experiments.studies.profiles import identifiability as ident
    from experiments.studies.profiles import study as profiles
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hidden", type=int, default=16)
    ap.add_argument("--name", choices=THETA_NAMES, default="mass")
    ap.add_argument("--steps", type=float, default=0.25, help="offset from theta*, scales")
    ap.add_argument("--iters", type=int, default=1000)
    ap.add_argument("--every", type=int, default=100)
    ap.add_argument("--delta", type=float, default=0.00851, help="delta, N**2")
    args = ap.parse_args()
    torch.set_num_threads(1)

    config, settings = profiles.load_profiles(
        ROOT / "experiments" / "configs" / "identifiability.yaml")
    settings = replace(settings, hidden=(args.hidden,), sloppy=1)
    t0 = time.process_time()
    rec = profiles.run_record((config, settings, 0))
    best = rec.best(args.hidden)
    data = rec.data[args.hidden]
    print(f"record fit: {best.row.data_cost:.6f} N² ({best.row.stop}), "
          f"{time.process_time() - t0:.1f} s CPU")
    value = best.row.theta[args.name] + args.steps * ident.scales(
        data.phi, data.target)[args.name]
    model = PGNNFeedforward(**profiles._fit_settings(settings, args.hidden),
                            features=config.features)
    net = model.new_network(data, None, best.beta)
    cost = SeparableCost(net, data.phi, data.target,
                         np.array([rec.lip[k] for k in THETA_NAMES]), model._weights(),
                         fit_theta=True, pinned={THETA_NAMES.index(args.name): value})
    costs = []

    def record(it, p, c):
        costs.append(c)
        if it % args.every == 0:
            r, jac = cost(p, True)
            fo = optim.first_order_measure(r, jac)
            fall = costs[max(0, len(costs) - 11)] - c
            print(f"  it {it:5d}  cost {c:.6f}  first_order {fo:.3g}  predicted {c * fo:.3g} N² "
                  f"({c * fo / args.delta:.3g} δ)  fall(10) {fall:.2g} N²")

    print(f"{args.name} pinned at {value:.6g} ({args.steps:+g} scales from theta*):")
    t0 = time.process_time()
    with single_threaded():
        res = optim.levenberg_marquardt(cost, net.get_nonlinear(), max_iter=args.iters,
                                        callback=record)
    print(f"stop {res.stop} after {res.iterations} iterations, mu {res.mu:.3g}, "
          f"{time.process_time() - t0:.1f} s CPU; fell {costs[0] - res.cost:.3g} N² "
          f"({(costs[0] - res.cost) / args.delta:.3g} δ)")
    r, jac = cost(res.p, True)
    d = np.linalg.norm(jac, axis=0)
    live = d > 1e-12 * d.max()
    js = jac[:, live] / d[live]
    w, v = np.linalg.eigh(js.T @ js)
    carried = (v.T @ (js.T @ r)) ** 2 / np.maximum(w, 1e-300)
    total = float(carried[w > w[-1] * 1e-12].sum())
    for frac in (1e-8, 1e-6, 1e-4):
        share = float(carried[(w > w[-1] * 1e-12) & (w < w[-1] * frac)].sum())
        print(f"  predicted decrease from directions of curvature < {frac:g} of the largest: "
              f"{share:.3g} of {total:.3g} N²")


if __name__ == "__main__":
    main()
