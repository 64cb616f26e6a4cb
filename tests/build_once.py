"""A session fixture's build done once per test run, even over pytest-xdist's workers."""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path


def build_once(tmp_path_factory, name: str, build: Callable[[Path], object]):
    """``build(folder)`` once per test run; its JSON-able return value to every caller.

    ``build`` writes what it makes into ``folder``. Alone, it runs in a fresh temporary folder.
    Under xdist, in a folder that all workers of the run share (the parent of each worker's base
    temp), under a file lock: the first worker to ask builds, the others wait and read the stored
    value (pytest-xdist's recipe for session fixtures), so a fixture that tests on both workers
    use costs one build. Tests must only read that folder."""
    if os.environ.get("PYTEST_XDIST_WORKER") is None:
        return build(tmp_path_factory.mktemp(name))
    from filelock import FileLock

    folder = tmp_path_factory.getbasetemp().parent / name
    stored = folder.with_name(f"{name}.json")
    with FileLock(str(folder.with_name(f"{name}.lock"))):
        if stored.is_file():
            return json.loads(stored.read_text())
        shutil.rmtree(folder, ignore_errors=True)  # what a build that raised left
        folder.mkdir()
        value = build(folder)
        stored.write_text(json.dumps(value))
        return value
