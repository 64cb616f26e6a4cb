"""Signals at random moments: how often a command fails its interruption promise (a stress run,
not a test).

The tests send Ctrl-C or SIGTERM at a few fixed moments (``test_cli.py``); a race is met only
at some. This script starts a real ``clm-sim run`` with a PGNN row (its fit pool and fork
server), or a ``clm-sim sweep`` on two workers, in a session of its own, waits until the command
has a child process, sleeps a random time drawn from ``--window``, sends the signal to the whole
process group (as a terminal does) and checks what docs/cli.md promises: exit 130 or 143, the
one line ``clm-sim: interrupted`` / ``terminated`` and nothing else on stderr, no process of the
command left (multiprocessing's resource tracker aside, which exits by itself), no result
(``run``), only whole task files (``sweep``). A command that ended before the signal is counted
apart, and so is one the signal reached once its result was written (whole: docs/cli.md's "a
signal after the results were written still ends with 130 or 143"). Every failure is printed
with its delay and the end of its stderr; the last line is
``failed=<k> of=<n> ended_first=<m> after_result=<j>``, exit code 1 if ``k > 0``.

    python benchmarks/stress_signals.py [--runs 40] [--signal TERM|INT] [--window 0.6 2.6]
                                        [--command run|sweep] [--twice 0 0.1] [--seed 0]

What it guards against (each fixed, see CHANGELOG.md): a worker forked at the moment of the
signal outliving the command with a traceback, a signal taken in a finalizer dropped, one
during the interpreter's shutdown lost, a fork server left stopped for good with ``--twice``,
the signal thread dying when stderr is a closed pipe. A command that
hangs is given 60 s, then killed and reported with what it left and those processes' states.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from sessions import session_processes, survivors  # noqa: E402  (the tests' helpers)
from small_config import SMALL_CONFIG  # noqa: E402

CONFIGS = {
    "run": SMALL_CONFIG + ("  - {kind: pgnn, training: sequential, hidden: 4, seeds: 2, "
                           "pgnn: {max_iter: 50}}\n"),
    "sweep": SMALL_CONFIG + "sweep:\n  grid:\n    seed: [1, 2, 3, 4]\n",
}


def one(command: str, sig: signal.Signals, delay: float, folder: Path,
        second: float | None = None) -> tuple[str, str]:
    """One command signalled ``delay`` s after its first child (and again ``second`` s later,
    if given): ("ok" | "ended first" | "after the result" | the faults, stderr)."""
    cfg = folder / "config.yaml"
    cfg.write_text(CONFIGS[command])
    out = folder / "out"
    args = [sys.executable, "-m", "experiments.cli", command, str(cfg), "--out", str(out),
            "--quiet"] + (["--workers", "2"] if command == "sweep" else [])
    proc = subprocess.Popen(args, cwd=folder, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True, start_new_session=True,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})
    while proc.poll() is None and len(session_processes(proc.pid)) <= 1:
        time.sleep(0.005)
    time.sleep(delay)
    ended_first = proc.poll() is not None
    try:
        os.killpg(proc.pid, sig)
        if second is not None:
            time.sleep(second)
            os.killpg(proc.pid, sig)
    except ProcessLookupError:
        pass
    try:
        _, err = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:  # a process of the command holds stderr: say which
        states = {}
        for pid in survivors(proc.pid):
            with contextlib.suppress(OSError):
                states[pid] = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        _, err = proc.communicate()
        return f"hung 60 s (command ended: {proc.returncode}; left, with their states: {states})", err
    if second is not None:  # docs/cli.md: the tracker may say it removed the pools' semaphores
        err = "".join(line for line in err.splitlines(keepends=True)
                      if "resource_tracker" not in line)
    if ended_first:
        return "ended first", err
    time.sleep(0.3)  # killed workers are reaped
    code, word = {signal.SIGINT: (130, "interrupted"), signal.SIGTERM: (143, "terminated")}[sig]
    faults = []
    if proc.returncode != code:
        faults.append(f"exit {proc.returncode}")
    if err.strip().splitlines() != [f"clm-sim: {word}"]:
        faults.append("stderr")
    left = survivors(proc.pid)
    if left:
        faults.append(f"left {sorted(left)}")
        for pid in left:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
    # The result may be there if the signal came once it was written (it is then whole: the
    # exit code and the line are still the signal's, docs/cli.md): counted apart.
    table = out / "table.json" if command == "sweep" or out.exists() else None
    if table is not None and table.exists():
        try:
            json.loads(table.read_text())
        except (OSError, ValueError):
            faults.append("table not whole")
    elif command == "run" and out.exists():
        faults.append("result folder without its table")
    if command == "sweep" and (out / "tasks").exists():
        for task in (out / "tasks").iterdir():
            try:
                json.loads(task.read_text())
                whole = not task.name.startswith(".")
            except (OSError, ValueError):
                whole = False
            if not whole:
                faults.append(f"task file {task.name}")
    late = table is not None and table.exists()
    return ", ".join(faults) or ("after the result" if late else "ok"), err


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=40)
    parser.add_argument("--signal", choices=["TERM", "INT"], default="TERM")
    parser.add_argument("--window", type=float, nargs=2, default=[0.6, 2.6],
                        metavar=("FROM_S", "TO_S"),
                        help="the delay after the command's first child, drawn uniformly")
    parser.add_argument("--command", choices=sorted(CONFIGS), default="run")
    parser.add_argument("--twice", type=float, nargs=2, default=None, metavar=("FROM_S", "TO_S"),
                        help="send the signal a second time, this long after the first (drawn "
                             "uniformly): the second ends the command at once")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    if not Path("/proc/self/stat").exists():
        parser.error("needs /proc (Linux)")
    sig = getattr(signal, f"SIG{args.signal}")
    rng = random.Random(args.seed)
    failed = ended_first = after_result = 0
    for i in range(args.runs):
        delay = rng.uniform(*args.window)
        second = rng.uniform(*args.twice) if args.twice else None
        with tempfile.TemporaryDirectory() as tmp:
            verdict, err = one(args.command, sig, delay, Path(tmp), second)
        if verdict == "ended first":
            ended_first += 1
        elif verdict == "after the result":
            after_result += 1
        elif verdict != "ok":
            failed += 1
            again = f", again {second:.3f} s later" if second is not None else ""
            print(f"run {i}, delay {delay:.2f} s{again}: {verdict}\n{err[-800:]}", flush=True)
    print(f"failed={failed} of={args.runs} ended_first={ended_first} "
          f"after_result={after_result}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
