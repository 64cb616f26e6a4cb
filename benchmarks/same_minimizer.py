"""Do the PGNN fits end where the code of another commit ends them? (a check, not a test).

Runs the same fits with the code of ``--baseline`` (checked out from git into a temporary
directory) and with this checkout, each in a subprocess, on the paper table's training data:
n_l = 16 and 8; the rows sequential, lambda = 0 with the paper's cost, lambda = 0 with weight
decay and continuation, lambda = 0.01 with weight decay; network draws of the table's seeds
``0 .. --seeds - 1``. Per row it prints the largest relative difference of the final training
cost and of theta_phy, the largest difference of theta_phy (and of its mean over the seeds) in
units of its seed-to-seed spread (the tolerance of docs/reproducibility.md for a mean of theta),
and how many fits changed their stop or their number of iterations.

    python benchmarks/same_minimizer.py [--seeds 5] [--baseline 5ea2910]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

ROWS = {"sequential": {"training": "sequential", "weight_decay": 1e-5},
        "lambda=0, paper's cost": {"lam": 0.0, "weight_decay": 0.0, "continuation_lam": 0.0},
        "lambda=0, decay + continuation": {"lam": 0.0, "weight_decay": 1e-5},
        "lambda=0.01, decay": {"lam": 0.01, "weight_decay": 1e-5}}

_FITS = textwrap.dedent("""
    import json, sys, time
    import numpy as np
    from controllers.pgnn import PGNNFeedforward, TrainingData
    d = np.load(sys.argv[1]); lip = json.loads(sys.argv[2]); jobs = json.loads(sys.argv[3])
    data = TrainingData(d["phi"], d["target"], float(d["ts"]))
    out = []
    for settings, (entropy, spawn) in jobs:
        rng = np.random.default_rng(np.random.SeedSequence(entropy, spawn_key=tuple(spawn)))
        c0 = time.process_time()
        old = {"continuation_lam": "continuation_lambda", "lam_diag": "lambda_diag"}  # < 11-26
        own = getattr(PGNNFeedforward, "__dataclass_fields__", None)  # a dataclass < 11-26
        if own is not None:
            settings = {(k if k in own else old.get(k, k)): v for k, v in settings.items()}
        m = PGNNFeedforward(**settings).fit_data(data=data, theta_lip=lip, rng=rng)
        f = m.fit_ if isinstance(m.fit_, dict) else m.fit_.to_json()  # a dict in older model files
        out.append({"cpu_s": time.process_time() - c0, "stop": f["stop"],
                    "iterations": f["iterations_total"], "theta": m.theta_,
                    "cost": f["data_cost"] + f["reg_cost"]})
    print(json.dumps(out))
""")


def run_fits(code_root: Path, npz: Path, theta_lip: dict, jobs: list) -> list[dict]:
    env = dict(os.environ, PYTHONPATH=str(code_root))
    got = subprocess.run([sys.executable, "-c", _FITS, str(npz), json.dumps(theta_lip),
                          json.dumps(jobs)], env=env, cwd=code_root, capture_output=True,
                         text=True, check=True)
    return json.loads(got.stdout.splitlines()[-1])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--baseline", default="5ea2910")
    args = ap.parse_args(argv)

    from controllers.pgnn import training_data
    from experiments.testbed import STREAM_NETWORK, Testbed, stream

    tb = Testbed.from_config(ROOT / "experiments/configs/paper_table.yaml")
    run = tb.training_run()
    theta_lip = dict(tb.fit_lip(run).theta_)
    data = training_data(tb.config.features, y=run.y, u=run.u, ts=run.ts)
    keys, jobs = [], []
    for hidden in (16, 8):
        for name, settings in ROWS.items():
            for s in range(args.seeds):
                seq = stream(tb.config.seed, STREAM_NETWORK, s)
                keys.append((name, hidden))
                jobs.append([{**settings, "hidden": hidden}, [seq.entropy, list(seq.spawn_key)]])
    with tempfile.TemporaryDirectory() as tmp:
        archive = subprocess.run(["git", "-C", str(ROOT), "archive", args.baseline],
                                 capture_output=True, check=True).stdout
        subprocess.run(["tar", "-x", "-C", tmp], input=archive, check=True)
        npz = Path(tmp) / "data.npz"
        np.savez(npz, phi=data.phi, target=data.target, ts=data.ts)
        old = run_fits(Path(tmp), npz, theta_lip, jobs)
        new = run_fits(ROOT, npz, theta_lip, jobs)
    print(f"{len(jobs)} fits, {args.baseline} against this checkout; CPU "
          f"{sum(o['cpu_s'] for o in old):.1f} s against {sum(n['cpu_s'] for n in new):.1f} s")
    print("| row | n_l | max rel. cost diff | max rel. θ diff | max θ diff / seed spread "
          "| mean θ diff / seed spread | stop differs | iterations differ |")
    print("|---|---|---|---|---|---|---|---|")
    for key in dict.fromkeys(keys):
        idx = [i for i, k in enumerate(keys) if k == key]
        o, n = [old[i] for i in idx], [new[i] for i in idx]
        names = list(o[0]["theta"])
        t_old = np.array([[f["theta"][k] for k in names] for f in o])
        t_new = np.array([[f["theta"][k] for k in names] for f in n])
        spread = t_old.std(axis=0, ddof=1) if len(idx) > 1 else np.zeros(len(names))
        unit = np.where(spread > 0, spread, np.inf)
        cost = max(abs(b["cost"] - a["cost"]) / a["cost"] for a, b in zip(o, n))
        rel = float(np.max(np.abs(t_new - t_old) / np.abs(t_old)))
        if len(idx) > 1:
            spreads = (f"| {np.max(np.abs(t_new - t_old) / unit):.2f} "
                       f"| {np.max(np.abs(t_new.mean(0) - t_old.mean(0)) / unit):.2f} ")
        else:  # one seed has no spread
            spreads = "| - | - "
        print(f"| {key[0]} | {key[1]} | {cost:.1e} | {rel:.1e} " + spreads +
              f"| {sum(a['stop'] != b['stop'] for a, b in zip(o, n))}/{len(idx)} "
              f"| {sum(a['iterations'] != b['iterations'] for a, b in zip(o, n))}/{len(idx)} |")


if __name__ == "__main__":
    main()
