"""One PGNN fit against its peers, in CPU seconds and as ratios (a benchmark, not a test).

The fit: the paper table's training data (its training run, filtered and decimated as the PGNN
fits it), n_l = 16, lambda = 0.01, weight decay 1e-5 (a row whose fits converge), network draws
of the table's seeds. Per seed, each contender starts from the same network draw:

* ``product``: ``PGNNFeedforward.fit_data`` (variable projection, Levenberg-Marquardt, the
  closed-form Jacobian);
* ``today``: the same fit with the code of commit ``--baseline`` (default 5ea2910, the autodiff
  Jacobian), checked out from git into a temporary directory and run in a subprocess right after
  the product's fit of the same seed: it must end where the product ends (same stop and
  iterations, costs within 1e-6 relative);
* ``least_squares``: ``scipy.optimize.least_squares`` on all parameters with a 2-point
  finite-difference Jacobian (what the authors' MATLAB toolbox does with ``lsqnonlin``), from
  the lemma's initialization, until its cost reaches the product's final cost (+1e-6 relative);
* ``lbfgs`` and ``adam``: ``torch.optim.LBFGS`` (strong Wolfe line search) and full-batch
  ``torch.optim.Adam`` (lr 1e-3) on all parameters of the torch module, same cost, same start,
  same target.

A peer that does not reach the target within ``--budget`` CPU seconds is reported as ``>``
the budget (its ratio is then a lower bound). Last, the floating-point rate of one iteration:
the FLOPs of its dense kernels (forward pass, SVD of the linear system, Jacobian, Kaufman
projection, normal matrix, eigendecomposition of the first-order test) over its measured CPU
time, as a fraction of the rate a large single-threaded DGEMM reaches on this core (the
practical peak) and of the nominal AVX2 peak (16 FLOP per cycle at the clock in /proc/cpuinfo).
Every timing is CPU (process) time on one thread: the fair figure on a shared machine.

    python benchmarks/bench_fit.py [--seeds 3] [--budget 60] [--baseline 5ea2910]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np
import scipy.optimize
import torch

from clm_sim.numerics import single_threaded
from controllers import optim
from controllers.pgnn import PGNNFeedforward, TrainingData, training_data
from controllers.pgnn.training import as_theta
from experiments.testbed import STREAM_NETWORK, Testbed, stream

ROOT = Path(__file__).resolve().parents[1]
SETTINGS = {"hidden": 16, "lam": 0.01, "weight_decay": 1e-5}

_TODAY = textwrap.dedent("""
    import json, sys, time
    import numpy as np
    from controllers.pgnn import PGNNFeedforward, TrainingData
    d = np.load(sys.argv[1]); lip = json.loads(sys.argv[2]); seeds = json.loads(sys.argv[3])
    data = TrainingData(d["phi"], d["target"], float(d["ts"]))
    out = []
    for entropy, spawn in seeds:
        rng = np.random.default_rng(np.random.SeedSequence(entropy, spawn_key=tuple(spawn)))
        c0 = time.process_time()
        m = PGNNFeedforward(**json.loads(sys.argv[4])).fit_data(data=data, theta_lip=lip, rng=rng)
        f = m.fit_ if isinstance(m.fit_, dict) else m.fit_.to_json()  # a dict in older model files
        out.append({"cpu_s": time.process_time() - c0, "stop": f["stop"],
                    "iterations": f["iterations"], "cost": f["data_cost"] + f["reg_cost"]})
    print(json.dumps(out))
""")


def product_fit(data, theta_lip, seq):
    c0 = time.process_time()
    model = PGNNFeedforward(**SETTINGS).fit_data(data=data, theta_lip=theta_lip,
                                                 rng=np.random.default_rng(seq))
    f = model.fit_
    return {"cpu_s": time.process_time() - c0, "stop": f.stop, "iterations": f.iterations,
            "cost": f.data_cost + f.reg_cost}


class Today:
    """The code of commit ``baseline``, checked out into a temporary directory, and the fit data
    beside it; :meth:`fit` runs one fit with it in a subprocess (None: not available)."""

    def __init__(self, data, theta_lip, baseline):
        self.tmp = tempfile.TemporaryDirectory()
        self.theta_lip, self.ok = theta_lip, True
        try:
            archive = subprocess.run(["git", "-C", str(ROOT), "archive", baseline],
                                     capture_output=True, check=True).stdout
            subprocess.run(["tar", "-x", "-C", self.tmp.name], input=archive, check=True)
        except (subprocess.CalledProcessError, FileNotFoundError) as exc:
            print(f"today: cannot check out {baseline} ({exc}); skipped", file=sys.stderr)
            self.ok = False
        self.npz = Path(self.tmp.name) / "data.npz"
        np.savez(self.npz, phi=data.phi, target=data.target, ts=data.ts)

    def fit(self, seq):
        if not self.ok:
            return None
        seeds = [[seq.entropy, list(seq.spawn_key)]]
        env = dict(os.environ, PYTHONPATH=self.tmp.name)
        got = subprocess.run([sys.executable, "-c", _TODAY, str(self.npz),
                              json.dumps(self.theta_lip), json.dumps(seeds),
                              json.dumps(SETTINGS)], env=env, cwd=self.tmp.name,
                             capture_output=True, text=True, check=True)
        return json.loads(got.stdout.splitlines()[-1])[0]


def start(data, theta_lip, seq):
    """The product's cost object and the full parameter vector ``(x, beta)`` of its start."""
    model = PGNNFeedforward(**SETTINGS)
    net = model.new_network(data, np.random.default_rng(seq))
    cost = model.training_cost(data, as_theta(theta_lip), net)
    beta = net.get_nonlinear()
    return model, net, cost, np.concatenate([cost._solve(beta)["x"], beta])


class _Reached(Exception):
    pass


def least_squares_to(data, theta_lip, seq, target, budget):
    """CPU seconds until ``least_squares`` (2-point Jacobian) costs at most ``target``."""
    _, _, cost, p0 = start(data, theta_lip, seq)
    c0 = time.process_time()
    state = {"best": np.inf}

    def fun(p):
        r = cost.full(p, False)
        value = float(r @ r)
        state["best"] = min(state["best"], value)
        if value <= target:
            raise _Reached
        if time.process_time() - c0 > budget:
            raise TimeoutError
        return r

    try:
        scipy.optimize.least_squares(fun, p0, jac="2-point", method="trf", x_scale="jac",
                                     ftol=1e-15, xtol=1e-15, gtol=1e-15, max_nfev=10**9)
    except _Reached:
        return time.process_time() - c0, state["best"]
    except TimeoutError:
        return None, state["best"]
    return None, state["best"]  # stopped by its own tests above the target


def torch_to(data, theta_lip, seq, target, budget, kind):
    """CPU seconds until torch's LBFGS or Adam, on the module's parameters, costs at most
    ``target`` (the same cost: mean squared error, deviation from theta_LIP, weight decay)."""
    model, net, cost, p0 = start(data, theta_lip, seq)
    k = cost.n_linear
    net.set_linear(p0[:4], p0[4:k - 1], float(p0[k - 1]))
    phi = torch.from_numpy(data.phi)
    target_t = torch.from_numpy(data.target)
    lam = torch.from_numpy(model.lam_matrix_diag())
    th_lip = torch.from_numpy(as_theta(theta_lip))
    weights = [p for n, p in net.mlp.named_parameters() if n.endswith("weight")]

    def loss():
        u = net(phi, phi)
        return (torch.mean((u - target_t) ** 2) + torch.sum(lam * (net.theta - th_lip) ** 2)
                + SETTINGS["weight_decay"] * sum(torch.sum(w * w) for w in weights))

    with torch.no_grad():
        check = float(loss())
    r0 = cost.full(p0, False)
    assert abs(check - float(r0 @ r0)) < 1e-9 * check, "torch loss is not the product's cost"
    params = list(net.parameters())
    if kind == "lbfgs":
        opt = torch.optim.LBFGS(params, lr=1.0, max_iter=20, history_size=20,
                                tolerance_grad=0.0, tolerance_change=0.0,
                                line_search_fn="strong_wolfe")
    else:
        opt = torch.optim.Adam(params, lr=1e-3)
    c0 = time.process_time()
    best = np.inf

    def closure():
        opt.zero_grad()
        value = loss()
        value.backward()
        return value

    while time.process_time() - c0 < budget:
        value = float(opt.step(closure).detach())
        best = min(best, value)
        if best <= target:
            return time.process_time() - c0, best
    return None, best


def iteration_rate(data, theta_lip, seq):
    """(FLOPs, CPU seconds) of one LM iteration of the product at its start: one evaluation
    with the Jacobian, one trial evaluation, normal matrix, gradient, first-order test, one
    damped solve; each measured as the mean of repeated runs."""
    _, _, cost, p0 = start(data, theta_lip, seq)
    beta = p0[cost.n_linear:]
    step = 1e-9 * np.ones_like(beta)

    def one():
        cost._cache = (None, None)
        r, J = cost(beta, True)
        A, g = J.T @ J, J.T @ r
        optim.first_order_measure(r, J, A, g)
        np.linalg.solve(A + np.eye(len(g)) * A.trace() * 1e-3, g)
        cost._cache = (None, None)
        cost(beta + step, False)

    one()
    n = 30
    c0 = time.process_time()
    for _ in range(n):
        one()
    seconds = (time.process_time() - c0) / n
    N, (m, k), p = cost.n, cost._A.shape, len(beta)
    widths = (4, *[layer.out_features for layer in cost.net.mlp.hidden])
    forward = sum(2 * N * a * b for a, b in zip(widths[:-1], widths[1:]))
    svd = 4 * m * k * k + 22 * k**3  # R-SVD with U (Golub & Van Loan, table 8.6.1)
    flops = (2 * (forward + svd + 2 * m * k)    # two evaluations: forward, SVD, x and r
             + 3 * N * p                          # closed-form Jacobian and its scaling
             + 4 * m * k * p                      # Kaufman's projection U (U' J)
             + m * p * p + 2 * m * p              # J'J (symmetric) and J'r
             + 9 * p**3 + p**3 // 3)              # eigendecomposition (first-order) and solve
    return flops, seconds


def dgemm_rate(n: int = 1500) -> float:
    a = np.random.default_rng(0).standard_normal((n, n))
    a @ a
    c0 = time.process_time()
    reps = 3
    for _ in range(reps):
        a @ a
    return 2 * n**3 * reps / (time.process_time() - c0)


def nominal_peak() -> float | None:
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as fh:
            mhz = next(float(line.split(":")[1]) for line in fh if line.startswith("cpu MHz"))
    except (OSError, StopIteration, ValueError):
        return None
    return 16 * mhz * 1e6  # AVX2: two 4-wide FMA units, 2 FLOP each, per cycle


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--budget", type=float, default=60.0,
                    help="CPU seconds per peer fit before it is reported as not reaching")
    ap.add_argument("--baseline", default="5ea2910", help="git commit of 'today's' fit")
    ap.add_argument("--no-peers", action="store_true", help="product and today only")
    args = ap.parse_args(argv)

    tb = Testbed.from_config(ROOT / "experiments/configs/paper_table.yaml")
    run = tb.training_run()
    theta_lip = dict(tb.fit_lip(run).theta_)
    data = training_data(tb.config.features, y=run.y, u=run.u, ts=run.ts)
    data = TrainingData(data.phi, data.target, data.ts)
    seqs = [stream(tb.config.seed, STREAM_NETWORK, s) for s in range(args.seeds)]
    print(f"data: {len(data.target)} samples; {SETTINGS}; CPU seconds, one thread; machine "
          f"may be shared (CPU time is what a fit costs)", flush=True)
    today = Today(data, theta_lip, args.baseline)
    rows = {"today": [], "least_squares": [], "lbfgs": [], "adam": []}
    for i, seq in enumerate(seqs):
        # One after the other, seed by seed: on a shared machine both see the same load.
        with single_threaded():
            mine = product_fit(data, theta_lip, seq)
        old = today.fit(seq)
        print(f"seed {i} product      : {mine['cpu_s']:7.2f} s, {mine['iterations']:4d} it, "
              f"{mine['stop']}, cost {mine['cost']:.9g} N²", flush=True)
        if old is not None:
            same = (old["stop"] == mine["stop"] and old["iterations"] == mine["iterations"]
                    and abs(old["cost"] - mine["cost"]) <= 1e-6 * old["cost"])
            rows["today"].append(old["cpu_s"] / mine["cpu_s"])
            print(f"seed {i} today        : {old['cpu_s']:7.2f} s, {old['iterations']:4d} it, "
                  f"{old['stop']}, cost {old['cost']:.9g} N² -> "
                  f"{'same end point' if same else 'DIFFERS'}",
                  flush=True)
        if args.no_peers:
            continue
        goal = mine["cost"] * (1 + 1e-6)
        with single_threaded():
            peers = {"least_squares": least_squares_to(data, theta_lip, seq, goal, args.budget),
                     "lbfgs": torch_to(data, theta_lip, seq, goal, args.budget, "lbfgs"),
                     "adam": torch_to(data, theta_lip, seq, goal, args.budget, "adam")}
        for name, (cpu, best) in peers.items():
            if cpu is None:
                rows[name].append(-args.budget / mine["cpu_s"])  # a lower bound
                print(f"seed {i} {name:13s}: > {args.budget:.0f} s (best cost {best:.9g} N²)",
                      flush=True)
            else:
                rows[name].append(cpu / mine["cpu_s"])
                print(f"seed {i} {name:13s}: {cpu:7.2f} s to the product's cost", flush=True)
    print("speed-up of the product (CPU time ratio, median over seeds; '>=': a peer missed the "
          "target within the budget in some seeds, whose ratios are lower bounds):")
    for name, ratios in rows.items():
        if ratios:
            r = np.array(ratios)
            bound = ">=" if np.any(r < 0) else ""
            print(f"  vs {name:13s}: {bound}{np.median(np.abs(r)):.1f}x")
    with single_threaded():
        flops, seconds = iteration_rate(data, theta_lip, seqs[0])
        gemm = dgemm_rate()
    nominal = nominal_peak()
    rate = flops / seconds
    print(f"one iteration: {flops / 1e6:.0f} MFLOP in {seconds * 1e3:.1f} ms = {rate / 1e9:.2f} "
          f"GFLOP/s; {rate / gemm:.0%} of a single-thread DGEMM ({gemm / 1e9:.1f} GFLOP/s)"
          + (f", {rate / nominal:.0%} of the nominal AVX2 peak ({nominal / 1e9:.1f} GFLOP/s)"
             if nominal else ""))


if __name__ == "__main__":
    main()
