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
# terminal's Ctrl-C hit, now and then, in tests/test_cli.py's signal tests. ``signal``: the
# signal reaches the main thread itself; ``poke``: as in a command line process, a thread of
# its own receives it and passes it on to the main thread as another signal
# (experiments.process.receive_signals), which SIGTERM hit in a run of the suite.
# ``commit``: between moving the earlier result aside and moving the new one into place.
RACE = """
import json, os, signal, sys, tempfile, time
from pathlib import Path
from clm_sim import outdir

where, which, mode = Path(sys.argv[1]), sys.argv[2], sys.argv[3]
real_mkdtemp, real_open, real_rename = tempfile.mkdtemp, os.open, os.rename
if mode == "poke":
    from experiments import process
    process.receive_signals()

def ctrl_c():
    os.kill(os.getpid(), signal.SIGINT)
    for _ in range(1000):  # bytecodes at which Python raises KeyboardInterrupt, unless held
        pass
    if mode == "poke":  # the receiving thread runs once this one lets it
        for _ in range(100):
            time.sleep(0.002)

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

def rename(src, dst, *args, **kwargs):
    real_rename(src, dst, *args, **kwargs)
    if which == "commit" and "partial-replaced" in str(dst):
        ctrl_c()

if which == "commit":  # an earlier result, replaced by this one
    (where / "out").mkdir()
    (where / "out" / "m").write_text("earlier")
tempfile.mkdtemp, os.open, os.rename = mkdtemp, open_, rename
try:
    with outdir.atomic_folder(where / "out", marker="m", what="w") as tmp:
        (tmp / "m").write_text("this run")
        ended = "finished"
except KeyboardInterrupt:
    ended = "interrupted"
print(json.dumps(ended))
"""


@pytest.mark.skipif(not hasattr(signal, "pthread_sigmask"), reason="POSIX signal masks")
@pytest.mark.parametrize("mode", ["signal", "poke"])
@pytest.mark.parametrize("which", ["probe", "partial", "lock", "commit"])
def test_ctrl_c_just_after_a_temporary_file_is_made_leaves_nothing(which, mode, tmp_path):
    """The probe of the output's parent, the temporary result folder and the lock file: each
    is made and recorded with Ctrl-C held, so the interrupted command removes it. A Ctrl-C
    while the result is moved into place takes effect once it is there: the folder holds this
    run's result, whole, and nothing else is left."""
    where = tmp_path / "place"
    where.mkdir()
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    out = subprocess.run([sys.executable, "-c", RACE, str(where), which, mode],
                         capture_output=True, text=True, timeout=120, env=env)
    left = sorted(p.name for p in where.iterdir())
    if mode == "poke" and out.returncode == 130:
        # The receiving thread ended the process itself (the main thread had not taken the
        # signal within ANSWER_S, e.g. on a loaded machine): the same promise holds.
        assert out.stderr.strip() == "clm-sim: interrupted", out.stderr
    else:
        assert out.returncode == 0, out.stderr
        assert json.loads(out.stdout) == "interrupted"
    if which == "commit":
        assert left == ["out"], left
        assert sorted(p.name for p in (where / "out").iterdir()) == ["figures", "m"]
        assert (where / "out" / "m").read_text() == "this run"
    else:
        assert left == [], left
