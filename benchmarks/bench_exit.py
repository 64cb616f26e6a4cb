"""What a process with the numerical libraries loaded pays to end (a benchmark, not a test).

A ``clm-sim`` command that has fitted PGNNs has torch, python-control, scipy.signal and numba
loaded, hundreds of thousands of objects; the interpreter's shutdown tears down every module and
runs full garbage collections that walk them. This script starts fresh processes that load the
libraries and end in one of three ways (interleaved):

- ``collected``: as Python ends a process;
- ``frozen``: the heap frozen first (``gc.freeze``), so those collections skip it;
- ``ended``: the exit handlers run, then ``os._exit``: no shutdown at all, as a ``clm-sim``
  command ends (:func:`experiments.processes.process.run`: the shutdown writes nothing of clm-sim's,
  and a signal that came during it would be lost);

and prints for each way the time from the process's last exit handler to its end as its parent
sees it (wall time; median and range over ``--runs``).

    python benchmarks/bench_exit.py [--runs 5] [--modules torch,control,scipy.signal,numba]
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CHILD = """
import atexit, gc, sys, time
for name in sys.argv[2].split(","):
    __import__(name)
if sys.argv[3] == "frozen":
    gc.freeze()
atexit.register(lambda: open(sys.argv[1], "w").write(repr(time.time())))
if sys.argv[3] == "ended":
    import os
    atexit._run_exitfuncs()
    os._exit(0)
"""


def one(stamp: Path, modules: str, how: str) -> float:
    """Seconds from the child's last exit handler to its end."""
    subprocess.run([sys.executable, "-c", CHILD, str(stamp), modules, how], check=True)
    ended = time.time()
    return ended - float(stamp.read_text())


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--modules", default="torch,control,scipy.signal,numba")
    args = parser.parse_args(argv)
    times: dict[str, list[float]] = {"collected": [], "frozen": [], "ended": []}
    with tempfile.TemporaryDirectory() as tmp:
        stamp = Path(tmp) / "stamp"
        for _ in range(args.runs):
            for how in times:
                times[how].append(one(stamp, args.modules, how))
    print(f"modules loaded: {args.modules}; {args.runs} runs each, interleaved")
    for how, values in times.items():
        print(f"exit {how:9s}: median {statistics.median(values):.2f} s "
              f"(range {min(values):.2f} to {max(values):.2f} s)")
    ratio = statistics.median(times["collected"]) / statistics.median(times["frozen"])
    print(f"ratio_collected_over_frozen={ratio:.1f}")
    print(f"ended_median_s={statistics.median(times['ended']):.3f}")


if __name__ == "__main__":
    main()
