"""The sweep store trusts no task file: a file that is not strict JSON, holds
NaN, belongs to another task or was edited, or is a link is said in one line, removed and its
task recomputed; no symbolic link inside a sweep's --out is written through."""

from __future__ import annotations

import json
import os

import pytest

from clm_sim.errors import UserError
from clm_sim.outdir import write_manifest
from experiments.sweeps.run import WHAT, _lock, check_output
from experiments.sweeps.store import ResultStore, task_key

VERSION = "0+test"


def _result(config: dict) -> tuple[str, dict]:
    key = task_key(config, VERSION)
    return key, {"status": "ok", "rows": [{"label": "LIP", "mae": 1e-6}], "key": key,
                 "overrides": {}, "code_version": VERSION, "config": config}


@pytest.fixture
def store(tmp_path):
    said = []
    s = ResultStore(tmp_path / "tasks").open()
    s.on_invalid = lambda path, why: said.append((path, why))
    s.said = said
    return s


def test_a_stored_result_is_read_back(store):
    key, result = _result({"seed": 1})
    store.put(key, result)
    assert store.get(key) == result and store.said == []


@pytest.mark.parametrize("damage, expected", [
    (lambda text, other: text[: len(text) // 2], "unreadable"),  # truncated by a crash
    (lambda text, other: text.replace("1e-06", "NaN"), "NaN"),
    (lambda text, other: other, "holds the result of task"),  # two files swapped
    (lambda text, other: text.replace('"seed": 1', '"seed": 7'), "does not hash to its key"),
    (lambda text, other: "[1]", "not a task result"),
    (lambda text, other: "[" * 100_000 + "]" * 100_000, "unreadable"),
    (lambda text, other: text.replace('"ok"', '"maybe"'), "neither ok nor failed"),
])
def test_a_damaged_task_file_is_said_removed_and_recomputed(store, damage, expected):
    key, result = _result({"seed": 1})
    other_key, other = _result({"seed": 2})
    store.put(key, result)
    store.put(other_key, other)
    path = store.path(key)
    path.write_text(damage(path.read_text(), store.path(other_key).read_text()))
    assert store.get(key) is None
    assert len(store.said) == 1 and store.said[0][0] == path and expected in store.said[0][1]
    assert not path.exists() and store.get(other_key) == other


def test_a_task_file_that_is_a_link_is_not_followed(store, tmp_path):
    key, result = _result({"seed": 1})
    target = tmp_path / "elsewhere.json"
    target.write_text(json.dumps(result))
    os.symlink(target, store.path(key))
    assert store.get(key) is None and "symbolic link" in store.said[0][1]
    assert target.read_text() == json.dumps(result)  # the target is untouched


@pytest.mark.parametrize("name", [".lock", "figures", "tasks", "table.json"])
def test_a_link_inside_the_output_folder_is_refused(tmp_path, name):
    out = tmp_path / "sweep"
    out.mkdir()
    (out / "sweep.resolved.yaml").write_text("base: {}\n")
    write_manifest(out, WHAT)
    victim = tmp_path / "victim"
    victim.mkdir() if name in ("figures", "tasks") else victim.write_text("keep me")
    os.symlink(victim, out / name)
    with pytest.raises(UserError, match="symbolic link"):
        check_output(out)


def test_the_lock_does_not_truncate_a_linked_file(tmp_path):
    out = tmp_path / "sweep"
    out.mkdir()
    victim = tmp_path / "victim"
    victim.write_text("keep me")
    os.symlink(victim, out / ".lock")
    with pytest.raises(OSError):
        _lock(out)
    assert victim.read_text() == "keep me"


# Task files that are not the result of their task: each is said, removed and recomputed.
ROWS = {
    "no rows": [],
    "rows not a list": {"label": "LIP", "mae": 1e-6},
    "negative mae": [{"label": "LIP", "mae": -1e-6}],
    "negative mean": [{"label": "LIP", "mae": {"r1": {"mean": -1.0, "std": 0.0}}}],
    "mae a string": [{"label": "LIP", "mae": "1e-6"}],
    "mae a bool": [{"label": "LIP", "mae": True}],
    "no metric": [{"label": "LIP"}],
    "row not an object": ["LIP"],
    "too many rows": [{"label": "LIP", "mae": 1e-6}] * 2,
    "negative force rms": [{"label": "LIP", "force_rms": {"a": {"inside": {"mean": -2}}}}],
}


@pytest.mark.parametrize("case", sorted(ROWS))
def test_rows_that_are_not_the_tasks_are_refused(store, case):
    config = {"seed": 1, "feedforwards": [{"kind": "lip"}]}
    key, result = _result(config)
    store.put(key, {**result, "rows": ROWS[case]})
    assert store.get(key) is None
    assert len(store.said) == 1 and not store.path(key).exists()


def test_rows_of_the_task_are_read(store):
    config = {"seed": 1, "feedforwards": [{"kind": "lip"}, {"kind": "none"}]}
    key, result = _result(config)
    rows = [{"label": "LIP", "mae": {"r1": {"mean": 1e-6, "std": 0.0}}},
            {"label": "none", "mae": {"r1": {"mean": 0.0, "std": None}}}]
    store.put(key, {**result, "rows": rows})
    assert store.get(key)["rows"] == rows and not store.said


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="POSIX FIFOs")
@pytest.mark.parametrize("kind", ["fifo", "folder"])
def test_a_task_file_that_is_not_a_regular_file_is_not_read(store, kind):
    """A FIFO in a task file's place would block the read forever: it is refused at once."""
    key, _ = _result({"seed": 3})
    path = store.path(key)
    os.mkfifo(path) if kind == "fifo" else path.mkdir()
    if kind == "fifo":
        assert store.get(key) is None
        assert "not a regular file" in store.said[0][1]
    else:  # a folder cannot be removed as a file: one line, left to the user
        with pytest.raises(UserError, match="Is a directory.*remove it to resume"):
            store.get(key)
