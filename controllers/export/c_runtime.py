"""The static C runtime of the export: the fragments in ``runtime/*.c`` (package data, shipped in
the wheel), which :mod:`controllers.export.c_source` and :mod:`controllers.export.c_stream` join
with the generated tables and laws. Each file holds the exact text it contributes (no template
fields): edit the C there, not in Python strings."""

from __future__ import annotations

from importlib.resources import files


def runtime(name: str) -> str:
    """The text of the runtime fragment ``name`` (e.g. ``"prelude.c"``)."""
    return files("controllers.export").joinpath("runtime").joinpath(name).read_bytes() \
        .decode("utf-8")
