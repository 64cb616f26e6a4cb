"""One LM iteration of the PGNN fit, the product's against the least arithmetic known for it
(a benchmark, not a test).

Times one LM iteration of a paper's-cost fit (lambda = 0, no weight decay: the rows that are
most of the paper table's iterations) on the paper table's training data, three ways, on one
thread, CPU time, for an accepted step (a rejected step adds a trial, on every side alike):

* ``product``: a trial evaluation (forward pass, the scaled linear system factorized by
  Cholesky QR twice, :class:`controllers.pgnn.cost.Range`), then at that point the Jacobian
  (closed form, Kaufman's projection in place; the linear solve cached), ``J'J``, ``J'r``, the
  first-order test and the damped Cholesky solve of
  :func:`controllers.optim.levenberg_marquardt`;
* ``reference``: the same step with the thin SVD of the linear system (the product's
  arithmetic before Cholesky QR; the SVD is still its fallback);
* ``restructured``: the least arithmetic known here for the same step, in numpy: the linear
  system solved through the Cholesky factor of its Gram matrix (numerically the weakest choice:
  it squares the condition number, which the lambda = 0 rows, nearly rank-deficient by design,
  do not tolerate everywhere), and the projected normal matrix formed as ``G'G - C'C`` block
  by block over the samples from the network's structure (``G = d f_NN / d beta`` never stored
  whole, ``C`` its product with the orthonormal basis of the linear system), then the same
  first-order test and damped solve. The product keeps two of its savings (no SVD, no second
  pass over the Jacobian to scale it) and not the other two: ``G'G - C'C`` is not the Gram
  matrix of any Jacobian, so its rounding (some ``1e-14 * ||G_j||**2``) lands in the flat
  directions that the first-order test and the damped step resolve down to ``1e-12`` of the
  largest curvature (in an exactly flat valley it made both wander:
  ``tests/test_profiles.py``), and the Gram matrix's Cholesky factor squares the condition
  number that the product's Cholesky QR repairs in its second pass.

It checks that the three give the same normal matrix and gradient at the start (relative
difference printed), and prints each rate, the product's ratio to the restructured one and
what the table's iterations cost at each rate (``--table``: the LM iterations at n_l = 16 and
8 that a ``table.json`` records as run by its command, default the page's
``docs/results/paper_table.json``; ``--iterations``: given instead).

    python benchmarks/bench_iteration_floor.py [--rounds 7] [--repeats 20]
                                               [--table DIR/table.json | --iterations N16,N8]
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
from controllers.pgnn.cost import Range  # noqa: E402
from controllers.pgnn.training import as_theta  # noqa: E402
from experiments.testbed import STREAM_NETWORK, Testbed, stream  # noqa: E402

BLOCK = 512  # samples per block of the restructured normal matrix (fits in L2 at n_l = 16)


def cost_at_start(data, theta_lip, hidden, seed):
    """The product's cost object of a paper's-cost fit (network draw 0 of the config's
    ``seed``) and the start's nonlinear parameters."""
    model = PGNNFeedforward(hidden=hidden, lam=0.0, weight_decay=0.0, continuation_lam=0.0)
    seq = stream(seed, STREAM_NETWORK, 0)
    net = model.new_network(data, np.random.default_rng(seq))
    cost = model.training_cost(data, as_theta(theta_lip), net)
    return cost, net.get_nonlinear()


def product_iteration(cost, beta):
    """One iteration of the product's fit: a trial evaluation at a new point, which is
    accepted, then the projected normal matrix and gradient there (its linear solve cached), the
    first-order test and a damped solve."""
    moved = [0]

    def one():
        moved[0] += 1
        b = beta + moved[0] * 1e-12  # a new point every time: no cache hit for the trial
        cost(b, False)
        r, J = cost(b, True)
        normal, g = J.T @ J, J.T @ r
        optim.first_order_from_normal(normal, g, float(r @ r))
        damped_solve(normal, g)
        return normal, g
    return one


def reference_iteration(cost, beta):
    """The same iteration with the SVD of the linear system and the Jacobian projected
    explicitly before ``J'J``."""
    moved = [0]

    def solve(b):
        h = cost.net.layer_outputs(b, cost.zs)
        A = cost._fill(h[1][-1].numpy())
        scale = np.linalg.norm(A, axis=0)
        span = Range.of(A / scale, exact=True)
        x = span.solve(cost._c) / scale
        return h, x, span.U, A @ x - cost._c

    def one():
        moved[0] += 1
        b = beta + moved[0] * 1e-12
        layers, x, U, r = solve(b)
        J = cost._beta_rows(b, x[cost.n_theta:cost.n_theta + cost.n_hidden], layers)
        J -= U @ (U.T @ J)
        normal, g = J.T @ J, J.T @ r
        optim.first_order_measure(r, J, normal, g)
        damped_solve(normal, g)
        return normal, g
    return one


def damped_solve(normal, g):
    """The damped Gauss-Newton step of the optimizer (Marquardt scaling, Cholesky)."""
    d = np.sqrt(np.diag(normal))
    f = scipy.linalg.cho_factor(normal / np.outer(d, d) + 1e-3 * np.eye(len(g)))
    return -scipy.linalg.cho_solve(f, g / d) / d


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
            damped_solve(normal, g)
            return normal, g
        return one


def cpu_ms(fn, repeats):
    fn()
    c0 = time.process_time()
    for _ in range(repeats):
        fn()
    return (time.process_time() - c0) / repeats * 1e3


SIDES = ("product", "reference", "restructured")


def iteration_ms(data, theta_lip, hidden, seed, sides=SIDES, rounds=7, repeats=20):
    """CPU ms of one LM iteration per side (the median of ``rounds`` interleaved rounds of
    ``repeats``: every side sees the same load) at ``hidden`` neurons, and each side's largest
    relative difference from the reference's normal matrix and gradient at the start (call
    inside :func:`clm_sim.numerics.single_threaded`)."""
    cost, beta = cost_at_start(data, theta_lip, hidden, seed)
    make = {"product": lambda: product_iteration(cost, beta),
            "reference": lambda: reference_iteration(cost, beta),
            "restructured": lambda: Restructured(cost).iteration(beta)}
    fns = {k: make[k]() for k in dict.fromkeys(("reference", *sides))}
    got = {k: fn() for k, fn in fns.items()}
    n0, g0 = got["reference"]
    diff = {k: (np.abs(n - n0).max() / np.abs(n0).max(),
                np.abs(g - g0).max() / np.abs(g0).max()) for k, (n, g) in got.items()}
    times = {k: [] for k in sides}
    for _ in range(rounds):
        for k in sides:
            times[k].append(cpu_ms(fns[k], repeats))
    return {k: float(np.median(v)) for k, v in times.items()}, diff


def table_iterations(path) -> list[int]:
    """The LM iterations a table's ``table.json`` records as run by its command, at n_l = 16
    and 8 (a start one fit took from another's cache counted once, where it ran)."""
    import json

    from experiments.table import FitSummary, lm_iterations

    counts = {16: 0, 8: 0}
    for row in json.loads(Path(path).read_text())["rows"]:
        if row.get("kind") == "pgnn" and row.get("hidden") in counts:
            counts[row["hidden"]] += lm_iterations([FitSummary.from_json(f)
                                                     for f in row["fits"]])[0]
    return [counts[16], counts[8]]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=20, help="iterations per round")
    ap.add_argument("--rounds", type=int, default=7,
                    help="rounds, the sides interleaved; the median round is printed")
    ap.add_argument("--iterations", default=None,
                    help="the table's LM iterations at n_l = 16 and 8 (instead of --table)")
    ap.add_argument("--table", default=str(ROOT / "docs/results/paper_table.json"),
                    help="a table.json to read the iterations run from (default: the page's)")
    args = ap.parse_args(argv)
    counts = ([int(v) for v in args.iterations.split(",")] if args.iterations
              else table_iterations(args.table))

    tb = Testbed.from_config(ROOT / "experiments/configs/paper_table.yaml")
    run = tb.training_run()
    theta_lip = dict(tb.fit_lip(run).theta_)
    d = training_data(tb.config.features, y=run.y, u=run.u, ts=run.ts)
    data = TrainingData(d.phi, d.target, d.ts)
    print(f"data: {len(data.target)} samples; one LM iteration of a paper's-cost fit "
          f"(lambda = 0), CPU ms on one thread", flush=True)
    sides = SIDES
    totals = dict.fromkeys(sides, 0.0)
    with single_threaded():
        for hidden, count in zip((16, 8), counts):
            ms, diff = iteration_ms(data, theta_lip, hidden, tb.config.seed, sides,
                                    args.rounds, args.repeats)
            for k in totals:
                totals[k] += ms[k] * count / 1e3
            print(f"n_l = {hidden:2d}: product {ms['product']:6.2f} ms, reference "
                  f"{ms['reference']:6.2f} ms, restructured {ms['restructured']:6.2f} ms; "
                  f"product / restructured {ms['product'] / ms['restructured']:.2f}x, "
                  f"reference / restructured {ms['reference'] / ms['restructured']:.2f}x",
                  flush=True)
            for k in ("product", "restructured"):
                print(f"         {k}: the reference's normal matrix within {diff[k][0]:.1e}, "
                      f"gradient within {diff[k][1]:.1e} (relative)")
    print(f"the table's {sum(counts):,} iterations ({counts[0]:,} at n_l = 16, {counts[1]:,} at "
          f"n_l = 8): " + ", ".join(f"{totals[k]:.1f} s at the {k} rate" for k in sides)
          + " (the fits' iterations alone)")
    print(f"restructured_s={totals['restructured']:.1f} product_s={totals['product']:.1f} "
          f"reference_s={totals['reference']:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
