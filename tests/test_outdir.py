"""clm_sim.outdir: a result folder appears whole or not at all, even under Ctrl-C."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

# Ctrl-C (SIGINT to the process itself) delivered right after the command created one of its
# temporary files or folders, before it could record it for the clean-up: the moment a
# terminal's Ctrl-C hit, now and then, in tests/test_cli.py's signal tests.
RACE = """
import json, os, signal, sys, tempfile
from pathlib import Path
from clm_sim import outdir

where, which = Path(sys.argv[1]), sys.argv[2]
real_mkdtemp, real_open = tempfile.mkdtemp, os.open

def ctrl_c():
    os.kill(os.getpid(), signal.SIGINT)
    for _ in range(1000):  # bytecodes at which Python raises KeyboardInterrupt, unless held
        pass

def mkdtemp(*args, **kwargs):
    made = real_mkdtemp(*args, **kwargs)
    if which in Path(made).name:
        ctrl_c()
    return made

def open_(path, *args, **kwargs):
    fd = real_open(path, *args, **kwargs)
    if which == "lock" and str(path).endswith(".lock"):
        ctrl_c()
    return fd

tempfile.mkdtemp, os.open = mkdtemp, open_
try:
    with outdir.atomic_folder(where / "out", marker="m", what="w"):
        ended = "finished"
except KeyboardInterrupt:
    ended = "interrupted"
print(json.dumps([ended, sorted(p.name for p in where.iterdir())]))
"""


@pytest.mark.skipif(not hasattr(signal, "pthread_sigmask"), reason="POSIX signal masks")
@pytest.mark.parametrize("which", ["probe", "partial", "lock"])
def test_ctrl_c_just_after_a_temporary_file_is_made_leaves_nothing(which, tmp_path):
    """The probe of the output's parent, the temporary result folder and the lock file: each
    is made and recorded with Ctrl-C held, so the interrupted command removes it."""
    where = tmp_path / "place"
    where.mkdir()
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    out = subprocess.run([sys.executable, "-c", RACE, str(where), which], capture_output=True,
                         text=True, timeout=120, env=env)
    assert out.returncode == 0, out.stderr
    ended, left = json.loads(out.stdout)
    assert ended == "interrupted" and left == [], (ended, left)
