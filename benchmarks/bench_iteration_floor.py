"""How far a cheaper arithmetic could take the paper table's fits (a benchmark, not a test).

For the paper table, whose fits run 12,268 LM iterations (``benchmarks/bench_table.py``), a
bar of 60 s of CPU allows under 5 ms per iteration even if nothing
else in the table cost anything. This script times one LM iteration of a paper's-cost fit (lambda = 0, no weight decay:
the rows that are 64 % of those iterations) on the paper table's training data, two ways, on one
thread, CPU time:

* ``product``: the product's iteration with an accepted step: a trial evaluation (forward pass,
  SVD of the scaled linear system), then at that point the Jacobian (closed form, Kaufman's
  projection; the linear solve cached), ``J'J`` and ``J'r``, the first-order test and a damped
  solve (a rejected step adds a trial, on both sides alike);
* ``restructured``: the least arithmetic known here for the same step, in numpy: the linear
  system solved through the Cholesky factor of its Gram matrix (numerically the weakest choice:
  it squares the condition number, which the lambda = 0 rows, nearly rank-deficient by design,
  would not tolerate everywhere), and the projected normal matrix formed as ``G'G - C'C`` block
  by block over the samples from the network's structure (``G = d f_NN / d beta`` never stored
  whole, ``C`` its product with the orthonormal basis of the linear system), then the same
  first-order test and damped solve.

It checks that both give the same normal matrix and gradient at the start (relative
difference printed), and prints the ratio and what the table's iterations would cost at each
rate (``--iterations``: the table's LM iterations at n_l = 16 and 8). The restructured
iteration is a floor for the arithmetic, not a method the product could adopt as it is: its
rounding differs, and the rows without a minimizer end elsewhere after 200 iterations when the
rounding moves (docs/performance.md).

    python benchmarks/bench_iteration_floor.py [--rounds 7] [--repeats 20]
                                           [--iterations 6353,5915]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from clm_sim.numerics import pin_portable_kernels  # noqa: E402

pin_portable_kernels()

import numpy as np  # noqa: E402
import scipy.linalg  # noqa: E402
import torch  # noqa: E402

from clm_sim.numerics import single_threaded  # noqa: E402
from controllers import optim  # noqa: E402
from controllers.pgnn import PGNNFeedforward, TrainingData, training_data  # noqa: E402
from controllers.pgnn.model import _as_theta  # noqa: E402
from experiments.testbed import STREAM_NETWORK, Testbed, stream  # noqa: E402

BLOCK = 512  # samples per block of the restructured normal matrix (fits in L2 at n_l = 16)


def cost_at_start(data, theta_lip, hidden, seed):
    """The product's cost object of a paper's-cost fit (network draw 0 of the config's
    ``seed``) and the start's nonlinear parameters."""
    model = PGNNFeedforward(hidden=hidden, lam=0.0, weight_decay=0.0, continuation_lam=0.0)
    seq = stream(seed, STREAM_NETWORK, 0)
    net = model.new_network(data, np.random.default_rng(seq))
    cost = model.training_cost(data, _as_theta(theta_lip), net)
    return cost, net.get_nonlinear()


def product_iteration(cost, beta):
    """One iteration of the product's fit: a trial evaluation at a new point (forward pass,
    SVD), which is accepted, then the Jacobian there (its linear solve cached), ``J'J``, ``J'r``,
    the first-order test and a damped solve."""
    moved = [0]

    def one():
        moved[0] += 1
        b = beta + moved[0] * 1e-12  # a new point every time: no cache hit for the trial
        cost(b, False)
        r, J = cost(b, True)
        normal, g = J.T @ J, J.T @ r
        optim.first_order_measure(r, J, normal, g)
        np.linalg.solve(normal + np.eye(len(g)) * normal.trace() * 1e-3, g)
        return normal, g
    return one


class Restructured:
    """The same LM iteration with the least arithmetic (module docstring); one hidden layer."""

    def __init__(self, cost):
        if cost.blocks != [("data", slice(0, cost.n))] or cost.n_theta != 4:
            raise SystemExit("the restructured iteration covers the paper's cost only")
        self.cost = cost
        self.zs = cost.zs.numpy()
        self.n_hidden = cost.n_hidden
        self.A = cost._A.copy()  # physical columns and the constant filled; hidden ones below
        self.c = cost._c
        self.hidden = cost.net.mlp.hidden[0]

    def solve(self, beta):
        nh = self.n_hidden
        w = torch.from_numpy(beta[:4 * nh].reshape(nh, 4))
        b = torch.from_numpy(beta[4 * nh:])
        h = torch.tanh(torch.nn.functional.linear(torch.from_numpy(self.zs), w, b)).numpy()
        A = self.A
        A[:, 4:4 + nh] = h * self.cost.sq
        scale = np.sqrt(np.einsum("ij,ij->j", A, A))
        As = A / scale
        L = np.linalg.cholesky(As.T @ As)
        xs = scipy.linalg.cho_solve((L, True), As.T @ self.c)
        x = xs / scale
        return h, As, L, x, A @ x - self.c

    def normal(self, beta, solved=None):
        nh, zs = self.n_hidden, self.zs
        h, As, L, x, r = solved if solved is not None else self.solve(beta)
        s = (1.0 - h * h) * (x[4:4 + nh] * self.cost.sq)
        p = 5 * nh
        N, P, g = np.zeros((p, p)), np.zeros((As.shape[1], p)), np.zeros(p)
        Jb = np.empty((BLOCK, p))
        for i in range(0, len(zs), BLOCK):
            sb, zb = s[i:i + BLOCK], zs[i:i + BLOCK]
            J = Jb[:len(sb)]
            np.multiply(sb[:, :, None], zb[:, None, :], out=J[:, :4 * nh].reshape(len(sb), nh, 4))
            J[:, 4 * nh:] = sb
            N += J.T @ J
            P += As[i:i + BLOCK].T @ J
            g += J.T @ r[i:i + BLOCK]
        C = scipy.linalg.solve_triangular(L, P, lower=True)  # U'J with U = As L^-T
        return N - C.T @ C, g, r

    def iteration(self, beta):
        """The same iteration as :func:`product_iteration`, restructured."""
        moved = [0]

        def one():
            moved[0] += 1
            b = beta + moved[0] * 1e-12
            normal, g, r = self.normal(b, self.solve(b))  # the trial's solve, reused
            d = np.sqrt(np.diag(normal))
            w, V = np.linalg.eigh(normal / np.outer(d, d))  # the first-order test
            keep = w > w[-1] * 1e-12
            proj = V[:, keep].T @ (g / d)
            float(proj @ (proj / w[keep]) / float(r @ r))
            f = scipy.linalg.cho_factor(normal + np.eye(len(g)) * normal.trace() * 1e-3)
            scipy.linalg.cho_solve(f, g)
            return normal, g
        return one


def cpu_ms(fn, repeats):
    fn()
    c0 = time.process_time()
    for _ in range(repeats):
        fn()
    return (time.process_time() - c0) / repeats * 1e3


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=20, help="iterations per round")
    ap.add_argument("--rounds", type=int, default=7,
                    help="rounds, the two sides interleaved; the median round is printed")
    ap.add_argument("--iterations", default="6353,5915",
                    help="the table's LM iterations at n_l = 16 and 8 (bench_table.py)")
    args = ap.parse_args(argv)
    counts = [int(v) for v in args.iterations.split(",")]

    tb = Testbed.from_config(ROOT / "experiments/configs/paper_table.yaml")
    run = tb.training_run()
    theta_lip = dict(tb.fit_lip(run).theta_)
    d = training_data(tb.config.features, y=run.y, u=run.u, ts=run.ts)
    data = TrainingData(d.phi, d.target, d.ts)
    print(f"data: {len(data.target)} samples; one LM iteration of a paper's-cost fit "
          f"(lambda = 0), CPU ms on one thread", flush=True)
    totals = {"product": 0.0, "restructured": 0.0}
    with single_threaded():
        for hidden, count in zip((16, 8), counts):
            cost, beta = cost_at_start(data, theta_lip, hidden, tb.config.seed)
            mine, floor = product_iteration(cost, beta), Restructured(cost).iteration(beta)
            (n1, g1), (n2, g2) = mine(), floor()
            dn = np.abs(n1 - n2).max() / np.abs(n1).max()
            dg = np.abs(g1 - g2).max() / np.abs(g1).max()
            # Interleaved rounds, the median of each side: both see the same load.
            rounds = {"product": [], "restructured": []}
            for _ in range(args.rounds):
                rounds["product"].append(cpu_ms(mine, args.repeats))
                rounds["restructured"].append(cpu_ms(floor, args.repeats))
            ms = {k: float(np.median(v)) for k, v in rounds.items()}
            for k in totals:
                totals[k] += ms[k] * count / 1e3
            print(f"n_l = {hidden:2d}: product {ms['product']:6.2f} ms, restructured "
                  f"{ms['restructured']:6.2f} ms ({ms['product'] / ms['restructured']:.2f}x); "
                  f"same normal matrix within {dn:.1e}, gradient within {dg:.1e} (relative)",
                  flush=True)
    print(f"the table's {sum(counts):,} iterations: {totals['product']:.0f} s at the product's "
          f"rate, {totals['restructured']:.0f} s at the restructured one (fits alone; the bar "
          f"is 60 s for the whole table)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
