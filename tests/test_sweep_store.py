"""The sweep store trusts no task file: a file that is not strict JSON, holds
NaN, belongs to another task or was edited, or is a link is said in one line, removed and its
task recomputed; no symbolic link inside a sweep's --out is written through."""

from __future__ import annotations

import json
import os

import pytest

from clm_sim.errors import UserError
from experiments.sweeps.run import _lock, check_output
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
