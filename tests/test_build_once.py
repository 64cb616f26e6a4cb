"""tests/build_once.py: a session fixture's build shared by pytest-xdist's workers."""

from __future__ import annotations

import pytest
from build_once import build_once


class _Factory:
    """A worker's ``tmp_path_factory``: its base temp inside the run's shared folder."""

    def __init__(self, run, worker):
        self.base = run / worker
        self.base.mkdir(parents=True, exist_ok=True)

    def getbasetemp(self):
        return self.base


def test_the_second_worker_reads_what_the_first_built(tmp_path, monkeypatch):
    monkeypatch.setenv("PYTEST_XDIST_WORKER", "gw0")
    calls = []

    def build(folder):
        calls.append(folder)
        (folder / "made.txt").write_text("x")
        return {"out": str(folder / "made.txt"), "code": 0}

    first = build_once(_Factory(tmp_path, "gw0"), "thing", build)
    second = build_once(_Factory(tmp_path, "gw1"), "thing", build)
    assert first == second and len(calls) == 1
    assert calls[0] == tmp_path / "thing" and (tmp_path / "thing" / "made.txt").is_file()
    # another name is another build
    build_once(_Factory(tmp_path, "gw1"), "other", build)
    assert len(calls) == 2


def test_a_build_that_raised_is_built_again_from_an_empty_folder(tmp_path, monkeypatch):
    monkeypatch.setenv("PYTEST_XDIST_WORKER", "gw0")

    def broken(folder):
        (folder / "half.txt").write_text("x")
        raise RuntimeError("build failed")

    with pytest.raises(RuntimeError):
        build_once(_Factory(tmp_path, "gw0"), "thing", broken)
    assert build_once(_Factory(tmp_path, "gw1"), "thing",
                      lambda folder: sorted(p.name for p in folder.iterdir())) == []


def test_without_xdist_every_test_run_builds_in_its_own_folder(tmp_path_factory, monkeypatch):
    monkeypatch.delenv("PYTEST_XDIST_WORKER", raising=False)
    folders = [build_once(tmp_path_factory, "thing", str) for _ in range(2)]
    assert folders[0] != folders[1]
