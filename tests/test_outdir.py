"""clm_sim.outdir: a result folder appears whole or not at all, even under Ctrl-C."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from clm_sim import outdir
from clm_sim.errors import UserError

# Ctrl-C (SIGINT to the process itself) delivered right after the command created one of its
# temporary files or folders, before it could record it for the clean-up: the moment a
# terminal's Ctrl-C hit, now and then, in tests/test_cli.py's signal tests. ``signal``: the
# signal reaches the main thread itself; ``poke``: as in a command line process, a thread of
# its own receives it and passes it on to the main thread as another signal
# (experiments.processes.process.receive_signals), which SIGTERM hit in a run of the suite.
# ``commit``: between moving the earlier result aside and moving the new one into place.
RACE = """
import json, os, signal, sys, tempfile, time
from pathlib import Path
from clm_sim import outdir

where, which, mode = Path(sys.argv[1]), sys.argv[2], sys.argv[3]
real_mkdtemp, real_open, real_rename = tempfile.mkdtemp, os.open, os.rename
if mode == "poke":
    from experiments.processes import process
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
    outdir.write_manifest(where / "out", "w")
tempfile.mkdtemp, os.open, os.rename = mkdtemp, open_, rename
try:
    with outdir.atomic_folder(where / "out", what="w") as tmp:
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
        assert sorted(p.name for p in (where / "out").iterdir()) == [outdir.MANIFEST,
                                                                     "figures", "m"]
        assert (where / "out" / "m").read_text() == "this run"
    else:
        assert left == [], left


def _result(out: Path, what: str = "w") -> None:
    with outdir.atomic_folder(out, what=what) as tmp:
        (tmp / "m.json").write_text("{}")
        (tmp / "figures" / "f.png").write_bytes(b"png")


def test_a_folder_of_clm_sims_own_files_is_replaced(tmp_path):
    """The manifest lists every file of a result: the next run of its kind replaces it."""
    _result(tmp_path / "o")
    listing = json.loads((tmp_path / "o" / outdir.MANIFEST).read_text())
    assert sorted(listing["files"]) == ["figures/f.png", "m.json"]
    assert listing["folders"] == ["figures"]
    with outdir.atomic_folder(tmp_path / "o", what="w") as tmp:
        (tmp / "n.json").write_text("{}")
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == [
        outdir.MANIFEST, "figures", "n.json"]


# What a user may have put in or beside a result (the result folder made by _result first):
# each makes the folder not clm-sim's own, so nothing is replaced or deleted.
FOREIGN = {
    "file beside": lambda o: (o / "precious.txt").write_text("x"),
    "file in a subfolder": lambda o: (o / "figures" / "notes.txt").write_text("x"),
    "folder": lambda o: (o / "mine").mkdir(),
    "hidden file": lambda o: (o / ".notes").write_text("x"),
    "edited result": lambda o: (o / "m.json").write_text('{"mine": 1}'),
    "same size edit": lambda o: (o / "m.json").write_text("[]"),
    "result replaced by a link": lambda o: ((o / "m.json").unlink(),
                                            (o / "m.json").symlink_to(o.parent / "x")),
    "manifest of another kind": lambda o: _rewrite(o, what="something else"),
    "manifest listing the user's file": lambda o: ((o / "a.txt").write_text("x"),
                                                   _rewrite(o, add="a.txt")),
}


def _rewrite(o: Path, *, what=None, add=None):
    listing = json.loads((o / outdir.MANIFEST).read_text())
    if what:
        listing["what"] = what
    if add:  # listed, but not with the content it has
        listing["files"][add] = {"bytes": 1, "sha256": "0" * 64}
    (o / outdir.MANIFEST).write_text(json.dumps(listing))


@pytest.mark.parametrize("case", sorted(FOREIGN))
def test_a_folder_with_anything_clm_sim_did_not_write_is_never_replaced(case, tmp_path):
    out = tmp_path / "o"
    _result(out)
    (tmp_path / "x").write_text("outside")
    FOREIGN[case](out)
    before = {p: (p.read_bytes() if p.is_file() else None) for p in out.rglob("*")}
    with pytest.raises(UserError) as err:
        outdir.check_output_folder(out, what="w")
    assert "\n" not in str(err.value) and str(out) in str(err.value)
    with pytest.raises(UserError):
        with outdir.atomic_folder(out, what="w") as tmp:
            (tmp / "n.json").write_text("{}")
    after = {p: (p.read_bytes() if p.is_file() else None) for p in out.rglob("*")}
    assert after == before


@pytest.mark.parametrize("marker", ["scores.json", "export.json", "diagnosis.json",
                                    "config.resolved.yaml", outdir.MANIFEST])
def test_a_marker_file_alone_does_not_make_a_folder_clm_sims(marker, tmp_path):
    """A folder that holds a result's file name (or a manifest that is not one clm-sim wrote)
    beside a user's file is not replaced."""
    out = tmp_path / "o"
    out.mkdir()
    (out / "precious.txt").write_text("x")
    (out / marker).write_text("{}")
    with pytest.raises(UserError, match="not written by clm-sim"):
        with outdir.atomic_folder(out, what="w"):
            pass
    assert (out / "precious.txt").read_text() == "x"


def test_an_empty_folder_is_used(tmp_path):
    (tmp_path / "o").mkdir()
    _result(tmp_path / "o")
    assert (tmp_path / "o" / "m.json").exists()


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="POSIX FIFOs")
def test_a_fifo_in_a_folder_is_listed_unread_and_never_replaced(tmp_path):
    """Hashing a FIFO would block for ever: it is listed without a hash, so a folder that holds
    one is never taken for clm-sim's own (a sweep resumed into it does not hang)."""
    out = tmp_path / "o"
    out.mkdir()
    (out / "a.json").write_text("{}")
    os.mkfifo(out / "pipe")
    outdir.write_manifest(out, "w")
    listing = json.loads((out / outdir.MANIFEST).read_text())
    assert listing["files"]["pipe"]["sha256"] is None
    with pytest.raises(UserError, match="holds pipe"):
        outdir.check_output_folder(out, what="w")
