"""The processes of a command started in a session of its own (``start_new_session``): what
the tests of interrupted commands (``test_cli.py``) and ``benchmarks/stress_signals.py`` check
is left of it. Reads ``/proc`` (Linux)."""

from __future__ import annotations

import os
from pathlib import Path


def session_processes(sid: int) -> list[int]:
    """Processes still alive in the session ``sid`` (a command started with
    ``start_new_session``: its workers inherit the session even once orphaned)."""
    alive = []
    # Listed, then read: a process may end in between (Path.glob's own stat of "N/stat" raised
    # ProcessLookupError there once), so only the read is tried.
    for pid in (name for name in os.listdir("/proc") if name.isdigit()):
        try:
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[3]) == sid and fields[0] != "Z":  # fields: state ppid pgrp session
            alive.append(int(pid))
    return alive


def survivors(sid: int) -> dict[int, bytes]:
    """The command lines of the processes left in session ``sid``, but for multiprocessing's
    resource tracker: not a worker, it exits by itself once the command's end closes its pipe."""
    out = {}
    for pid in session_processes(sid):
        try:
            cmdline = Path(f"/proc/{pid}/cmdline").read_bytes()
        except OSError:
            continue  # ended meanwhile
        if cmdline and b"resource_tracker" not in cmdline:  # empty: its memory is gone, exiting
            out[pid] = cmdline[:300]
    return out
