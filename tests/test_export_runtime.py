"""The static C runtime of the export lives in ``controllers/export/runtime/`` and ships as
package data: an installed wheel must hold every fragment the emitters read."""

from __future__ import annotations

import ast
import fnmatch
import tomllib
from pathlib import Path

import controllers

ROOT = Path(__file__).resolve().parents[1]
EXPORT = Path(controllers.__file__).parent / "export"
READERS = ("runtime", "template")  # controllers.export.c_runtime


def _read_fragments() -> set[str]:
    """Names passed to ``runtime(...)``/``template(...)`` anywhere in ``controllers/export``."""
    names = set()
    for path in EXPORT.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if (isinstance(node, ast.Call) and getattr(node.func, "id", None) in READERS
                    and isinstance(node.args[0], ast.Constant)):
                names.add(node.args[0].value)
    return names


def test_every_fragment_read_exists_and_every_fragment_is_read():
    read = _read_fragments()
    on_disk = {p.name for p in (EXPORT / "runtime").iterdir()}
    assert read and read == on_disk


def _glob_matches(rel: str, pattern: str) -> bool:
    """setuptools' package-data glob: ``*`` does not cross a ``/``."""
    a, b = rel.split("/"), pattern.split("/")
    return len(a) == len(b) and all(fnmatch.fnmatchcase(x, y) for x, y in zip(a, b))


def test_glob_rule_is_setuptools_own():
    assert _glob_matches("export/runtime/a.c", "export/runtime/*.c")
    assert not _glob_matches("export/runtime/a.c", "export/*.c")


def test_package_data_ships_every_fragment():
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())
    globs = config["tool"]["setuptools"]["package-data"]["controllers"]
    for path in (EXPORT / "runtime").iterdir():
        rel = path.relative_to(EXPORT.parent).as_posix()
        assert any(_glob_matches(rel, g) for g in globs), rel
