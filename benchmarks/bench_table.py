"""Where the paper table's CPU goes, stage by stage and row by row (a benchmark, not a test).

Runs a table config (default ``experiments/configs/paper_table.yaml``) through the runner's own
code (:func:`experiments.runner._run`, every file written into a temporary folder) and counts
the CPU of each stage where it is spent:

* ``start-up and imports``: the interpreter and the modules a ``clm-sim run`` imports before
  its first computation;
* ``training run and LIP``: the PID design, the dithered closed-loop run, the LIP;
* ``fits``: the PGNN fits (their LM iterations counted, every start: a start an earlier row ran
  from the same draw is reused, not run);
* ``replays``: the closed loops on the references (the simulation);
* ``references and features``: the references, their filtered features, the network's force
  on them, the training range's masks;
* ``figures``: the tracking and feedforward figures (matplotlib imported on the way);
* ``writing``: the records, models and tables written;
* ``rest``: whatever a row's evaluation spends beside the above (metrics, fit records).

Default: every fit in this process, pinned to one core, so that every CPU second is counted
here (the runner uses its worker pool only with more than one core). ``--pool``: the worker
pool as ``clm-sim run`` uses it on this machine's cores; the fits then run in the pool's
processes, whose CPU (their start-up, imports and transfers included) is counted as
``worker processes``, and what the main process spends waiting and receiving as ``fits``.
The difference of the two runs' totals is what the pool costs.

    python benchmarks/bench_table.py [--config experiments/configs/paper_table.yaml]
                                     [--rows 2,3] [--seeds 10] [--pool]

Every timing is CPU time (``time.process_time`` in this process, ``getrusage`` of the
children): on a shared machine the fair figure. At the end, in the same process and sitting,
it times one LM iteration at the restructured rate (``bench_iteration_floor.py``'s least
arithmetic, n_l = 16 and 8) and prints the bar of the table's cost: its CPU against that rate
times the LM iterations its ``table.json`` records as run (a start taken from another fit's
cache runs none, and is counted apart as reused). ``--no-floor`` leaves that out.
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import json
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from clm_sim.numerics import pin_portable_kernels  # noqa: E402

pin_portable_kernels()

STAGES = ("start-up and imports", "training run and LIP", "fits", "replays",
          "references and features", "figures", "writing", "rest")
OUTER = ("training run and LIP", "figures", "writing")  # what runs inside them is theirs


def _children_cpu() -> float:
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


class Clock:
    """CPU seconds per stage; a stage entered inside another is counted once, in the inner
    (inside one of :data:`OUTER`, in that one)."""

    def __init__(self):
        self.spent = collections.Counter()
        self._stack: list[str] = []
        self._t = time.process_time()

    def _switch(self):
        now = time.process_time()
        if self._stack:
            self.spent[self._stack[-1]] += now - self._t
        self._t = now

    def wrap(self, stage: str, fn):
        def wrapper(*a, **k):
            if self._stack and self._stack[-1] in OUTER:  # e.g. the training run's loop
                return fn(*a, **k)
            self._switch()
            self._stack.append(stage)
            try:
                return fn(*a, **k)
            finally:
                self._switch()
                self._stack.pop()
        return wrapper

    def patch(self, stage: str, owner, *names: str):
        for name in names:
            setattr(owner, name, self.wrap(stage, getattr(owner, name)))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default=str(ROOT / "experiments/configs/paper_table.yaml"))
    ap.add_argument("--rows", default="", help="indices of the rows to run (default: all)")
    ap.add_argument("--seeds", type=int, default=None, help="seeds per PGNN row (default: "
                    "the config's)")
    ap.add_argument("--pool", action="store_true",
                    help="the fits on the worker pool, as clm-sim run (default: in this process)")
    ap.add_argument("--no-floor", action="store_true",
                    help="do not time the restructured rate at the end (no bar printed)")
    args = ap.parse_args(argv)
    if not args.pool:
        try:  # one core: the fits run in this process (experiments.processes.workers.map_fits)
            os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
        except (AttributeError, OSError):
            pass

    startup = time.process_time()  # the interpreter and the imports above
    clock = Clock()
    t0 = time.process_time()
    import clm_sim.loop
    import experiments.testbed as testbed
    from controllers import optim
    from controllers.pgnn import PGNNFeedforward
    from experiments import plots, runner
    from experiments.report import table_json, table_md
    from experiments.config import load_config
    from experiments.processes import workers
    from clm_sim import features
    clock.spent["start-up and imports"] = startup + time.process_time() - t0
    clock._t = time.process_time()

    config = load_config(args.config)
    specs = list(config.feedforwards)
    if args.rows:
        specs = [specs[int(i)] for i in args.rows.split(",")]
    if args.seeds is not None:
        specs = [dataclasses.replace(s, seeds=args.seeds) if s.kind == "pgnn" else s
                 for s in specs]
    config = dataclasses.replace(config, feedforwards=tuple(specs))

    iterations, per_row, label = collections.Counter(), {}, [None]
    lm = optim.levenberg_marquardt

    def counted(*a, **k):  # the LM iterations actually run (a reused start runs none)
        res = lm(*a, **k)
        iterations[label[0]] += res.iterations
        return res

    optim.levenberg_marquardt = counted
    testbed_cls = testbed.Testbed
    clock.patch("training run and LIP", testbed_cls, "training_run", "fit_lip")
    clock.patch("fits", testbed_cls, "fit_row")
    clock.patch("replays", testbed, "simulate")
    clock.patch("references and features", testbed_cls, "reference")
    clock.patch("references and features", PGNNFeedforward, "filtered_features", "parts")
    clock.patch("references and features", features.TrainingRange, "of", "beyond")
    clock.patch("figures", plots, "tracking_figure", "feedforward_figure", "save")
    clock.patch("writing", runner, "save_npz")
    clock.patch("writing", PGNNFeedforward, "save")
    clock.patch("writing", table_json, "to_json")
    clock.patch("writing", table_md, "to_markdown", "to_csv")
    evaluate = testbed_cls.evaluate
    fit_lip, seen = testbed_cls.fit_lip, {}

    def keep_lip(self, run, *a, **k):  # the training run and LIP, for the floor's fits
        lip = fit_lip(self, run, *a, **k)
        seen.setdefault("run", (run, lip))
        return lip

    testbed_cls.fit_lip = keep_lip

    def evaluate_row(self, spec, *a, **k):
        label[0] = spec.label()
        before = dict(clock.spent)
        res = evaluate(self, spec, *a, **k)
        per_row[spec.label()] = {s: clock.spent[s] - before.get(s, 0.0) for s in STAGES}
        stops = collections.Counter(m.fit_.stop for m in res.models
                                    if isinstance(m, PGNNFeedforward))
        per_row[spec.label()]["stops"] = ", ".join(f"{n} {k}" for k, n in sorted(stops.items()))
        return res

    testbed_cls.evaluate = clock.wrap("rest", evaluate_row)

    children0 = _children_cpu()
    with tempfile.TemporaryDirectory(prefix="bench_table_") as tmp:
        out = Path(tmp) / "out"
        for sub in ("runs", "params", "figures"):
            (out / sub).mkdir(parents=True)
        run_all = clock.wrap("rest", runner._run)
        run_all(config, out, testbed.Progress(quiet=True), args.config)
        workers.stop_fits()  # the pool's workers reaped: their CPU is the children's
        children = _children_cpu() - children0
        clock._switch()
        whole = time.process_time()
        recorded = json.loads((out / "table.json").read_text()).get("lm_iterations", {})
        by_hidden = collections.Counter()
        for row in json.loads((out / "table.json").read_text())["rows"]:
            if row.get("kind") == "pgnn":
                by_hidden[row["hidden"]] += sum(f["iterations_run"] for f in row["fits"])

    print(f"{'row':<72} {'fits':>6} {'replays':>8} {'refs':>5} {'rest':>5} "
          f"{'iterations':>10} {'per it':>7}  stops")
    for name, spent in per_row.items():
        its = iterations[name]
        per_it = f"{spent['fits'] / its * 1e3:.1f} ms" if its and not args.pool else ""
        print(f"{name[:72]:<72} {spent['fits']:6.1f} {spent['replays']:8.1f} "
              f"{spent['references and features']:5.1f} {spent['rest']:5.1f} {its:10d} "
              f"{per_it:>7}  {spent['stops']}")
    total_its = sum(iterations.values())
    print(f"LM iterations run: {total_its:,} counted here; table.json records "
          f"{recorded.get('run', 0):,} run and {recorded.get('reused', 0):,} reused "
          f"(taken from another fit's start cache)")
    print("stage                              CPU s")
    for stage in STAGES:
        print(f"  {stage:<32} {clock.spent[stage]:7.1f}")
    if args.pool:
        print(f"  {'worker processes':<32} {children:7.1f}")
    print(f"  {'this process, in all':<32} {whole:7.1f}")
    print(f"total_cpu_s={whole + children:.1f} fits_s={clock.spent['fits'] + children:.1f} "
          f"not_fitting_s={whole - clock.spent['fits']:.1f} iterations={total_its}")
    if args.no_floor or not by_hidden or "run" not in seen:
        return 0
    floor_s = restructured_floor(config, *seen["run"], by_hidden)
    print(f"bar: the table's CPU {whole + children:.1f} s against {floor_s:.1f} s at the "
          f"restructured rate for its {sum(by_hidden.values()):,} iterations run: "
          f"{(whole + children) / floor_s:.2f}x (bar 1.5x)")
    print(f"floor_s={floor_s:.1f} bar_ratio={(whole + children) / floor_s:.3f}")
    return 0


def restructured_floor(config, run, lip, by_hidden) -> float:
    """CPU seconds of ``by_hidden`` (neurons -> LM iterations) at the restructured rate of
    ``bench_iteration_floor.py``, timed now on this table's training data (n_l other than 16
    and 8: the rate of the nearer of the two)."""
    from bench_iteration_floor import iteration_ms

    from clm_sim.numerics import single_threaded
    from controllers.pgnn import TrainingData, training_data

    d = training_data(config.features, y=run.y, u=run.u, ts=run.ts)
    data = TrainingData(d.phi, d.target, d.ts)
    rate = {}
    with single_threaded():
        for hidden in (16, 8):
            ms, _ = iteration_ms(data, dict(lip.theta_), hidden, config.seed,
                                 sides=("restructured",))
            rate[hidden] = ms["restructured"]
            print(f"restructured rate at n_l = {hidden}: {rate[hidden]:.2f} ms per iteration "
                  f"({by_hidden.get(hidden, 0):,} iterations run)")
    return sum(n * rate[min(rate, key=lambda k: abs(k - h))] for h, n in by_hidden.items()) / 1e3


if __name__ == "__main__":
    raise SystemExit(main())
