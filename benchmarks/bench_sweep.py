"""Sweep throughput: the same 60-task sweep run serially (one worker) and in parallel.

The tasks are those of ``experiments/configs/sweep_lambda_hidden.yaml`` (6 lambda x 2 n_l x
5 seeds, one PGNN and the LIP per task) with the training run shortened to one pass of r1
(``--full`` keeps the three passes): throughput depends on the number of tasks and how evenly they
spread over the workers, not on the horizon. Each run starts from an empty result store.

    python benchmarks/bench_sweep.py [--workers 2] [--full]

Prints both wall times, their ratio (target >= 1.8 on 2 cores), the CPU time the workers used and
the load average: on a shared machine, other processes take cores from the runs (the 'cores busy'
figure, CPU / wall, then falls below the worker count). Also checks that both runs give the same
table, bit for bit.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import tempfile
import time
from pathlib import Path

import yaml

from experiments.sweeps.grid import load_sweep
from experiments.sweeps.run import run_sweep

CONFIG = Path(__file__).resolve().parent.parent / "experiments" / "configs" / \
    "sweep_lambda_hidden.yaml"


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)  # workers are joined at the end
    return usage.ru_utime + usage.ru_stime


def timed_sweep(config: Path, out: Path, workers: int) -> tuple[float, float, list]:
    """Wall time (s), CPU time of the worker processes (s) and the table rows."""
    cpu0, start = _children_cpu(), time.perf_counter()
    outcome = run_sweep(load_sweep(config), out, workers=workers, quiet=True)
    wall = time.perf_counter() - start
    cpu = _children_cpu() - cpu0
    if outcome.exit_code:
        raise SystemExit(f"{out}: {len(outcome.failures)} tasks failed: {outcome.failures[:3]}")
    return wall, cpu, json.loads((out / "table.json").read_text())["rows"]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--workers", type=int, default=2, help="parallel workers (default 2)")
    p.add_argument("--full", action="store_true", help="the study's full training run")
    args = p.parse_args()

    data = yaml.safe_load(CONFIG.read_text())
    if not args.full:
        data["training"] = {"repeats": 1}
    with tempfile.TemporaryDirectory(prefix="bench_sweep_") as tmp:
        tmp = Path(tmp)
        config = tmp / "bench.yaml"
        config.write_text(yaml.safe_dump(data, sort_keys=False))
        n = len(load_sweep(config).tasks)
        print(f"{n} tasks ({CONFIG.name}, training repeats "
              f"{data.get('training', {}).get('repeats', 3)}); load average before "
              f"{os.getloadavg()[0]:.2f}", flush=True)
        serial, cpu_1, rows_1 = timed_sweep(config, tmp / "serial", 1)
        print(f"serial   (1 worker):  {serial:8.1f} s wall, {cpu_1:7.1f} s CPU in workers "
              f"(cores busy {cpu_1 / serial:.2f})", flush=True)
        parallel, cpu_n, rows_n = timed_sweep(config, tmp / "parallel", args.workers)
        print(f"parallel ({args.workers} workers): {parallel:8.1f} s wall, {cpu_n:7.1f} s CPU in "
              f"workers (cores busy {cpu_n / parallel:.2f})")
        ratio = serial / parallel
        print(f"speed-up {ratio:.2f}x (target >= 1.8x on 2 cores): "
              f"{'met' if ratio >= 1.8 else 'NOT met'}; load average after "
              f"{os.getloadavg()[0]:.2f}")
        print(f"tables identical: {rows_1 == rows_n}")


if __name__ == "__main__":
    main()
