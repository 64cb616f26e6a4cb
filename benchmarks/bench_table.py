"""Where the paper table's CPU goes, row by row (a benchmark, not a test).

Runs the rows of a table config (default ``experiments/configs/paper_table.yaml``) the way
``clm-sim run`` does (:meth:`experiments.testbed.Testbed.evaluate`), but in this one process on
one core, so that every CPU second is counted in one place, and prints per row: the CPU of its
PGNN fits, of its closed-loop replays (the simulation) and of the rest of ``evaluate`` (the
feedforward: the filtered features and the network's force on every reference sample, the peak
force, the fit records); the LM iterations its fits ran (every start: the draw and, where the
row uses one, the continuation's two; a start an earlier row ran from the same draw is reused,
not run) and the fits' stops (and each start's). The identifiability profiles are their own
study (``clm-sim study experiments/configs/identifiability.yaml``), timed with ``/usr/bin/time``.

    python benchmarks/bench_table.py [--config experiments/configs/paper_table.yaml]
                                     [--rows 2,3] [--seeds 10]

Every timing is CPU time of this process (``time.process_time``): on a shared machine the
fair figure. The fits run in-process because the process is pinned to one core (the runner
uses its worker pool only with more than one), which changes no result (every fit is
single-threaded, docs/performance.md).
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from clm_sim.numerics import pin_portable_kernels  # noqa: E402

pin_portable_kernels()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default=str(ROOT / "experiments/configs/paper_table.yaml"))
    ap.add_argument("--rows", default="", help="indices of the rows to run (default: all)")
    ap.add_argument("--seeds", type=int, default=None, help="seeds per PGNN row (default: "
                    "the config's)")
    args = ap.parse_args(argv)
    try:  # one core: the fits run in this process (experiments.workers.map_fits)
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    except (AttributeError, OSError):
        pass

    t_start = time.process_time()
    from controllers.pgnn import PGNNFeedforward
    from experiments.config import load_config
    from experiments.testbed import Testbed

    config = load_config(args.config)
    tb = Testbed(config, progress=lambda s: None)
    clock = collections.Counter()

    def timed(key, fn):
        def wrapper(*a, **k):
            t0 = time.process_time()
            try:
                return fn(*a, **k)
            finally:
                clock[key] += time.process_time() - t0
        return wrapper

    from controllers import optim
    lm = optim.levenberg_marquardt

    def counted(*a, **k):  # the LM iterations actually run (a reused start runs none)
        res = lm(*a, **k)
        clock["run"] += res.iterations
        return res

    optim.levenberg_marquardt = counted
    tb.fit_row = timed("fit", tb.fit_row)
    t0 = time.process_time()
    run = tb.training_run()
    lip = tb.fit_lip(run)
    setup = time.process_time() - t0
    from experiments import testbed
    testbed.simulate = timed("replay", testbed.simulate)  # the closed loops of the replays
    print(f"imports and config {t0 - t_start:.1f} s, training run and LIP {setup:.1f} s "
          f"(CPU)")
    rows = [int(i) for i in args.rows.split(",") if i] or range(len(config.feedforwards))
    print(f"{'row':<74} {'fits':>6} {'replays':>8} {'other':>6} {'iterations':>10} "
          f"{'per it':>7}  stops")
    total = collections.Counter()
    for i in rows:
        spec = config.feedforwards[i]
        if args.seeds is not None and spec.kind == "pgnn":
            spec = dataclasses.replace(spec, seeds=args.seeds)
        clock.clear()
        t0 = time.process_time()
        res = tb.evaluate(spec, run, lip)
        whole = time.process_time() - t0
        models = [m for m in res.models if isinstance(m, PGNNFeedforward)]
        its = int(clock["run"])
        stops = collections.Counter(m.fit_.stop for m in models)
        starts = collections.Counter(f"{s.start}:{s.stop}" for m in models
                                     for s in m.fit_.starts)
        other = whole - clock["fit"] - clock["replay"]
        per_it = f"{clock['fit'] / its * 1e3:.1f} ms" if its else ""
        print(f"{spec.label()[:74]:<74} {clock['fit']:6.1f} {clock['replay']:8.1f} "
              f"{other:6.1f} {its:10d} {per_it:>7}  "
              + ", ".join(f"{n} {k}" for k, n in sorted(stops.items()))
              + ("" if not models else "  [" + ", ".join(f"{n} {k}" for k, n in
                                                        sorted(starts.items())) + "]"))
        total.update(fit=clock["fit"], replay=clock["replay"], other=other, iterations=its)
    print(f"{'all rows':<74} {total['fit']:6.1f} {total['replay']:8.1f} {total['other']:6.1f} "
          f"{total['iterations']:10d}")
    print(f"total {time.process_time() - t_start:.1f} s CPU in this process")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
