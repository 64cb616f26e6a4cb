"""The static C runtime of the export: the fragments in ``runtime/*.c`` (package data, shipped in
the wheel), which :mod:`controllers.export.c_source` and :mod:`controllers.export.c_stream` join
with the generated tables and laws, and the header ``runtime/header.h``. A ``.c`` fragment holds
the exact text it contributes; the header is a :class:`string.Template` whose ``${name}``
fields are the model's numbers and statements (C has no ``$``; a literal one is ``$$``). Edit the
C there, not in Python strings."""

from __future__ import annotations

from importlib.resources import files
from string import Template


def runtime(name: str) -> str:
    """The text of the runtime fragment ``name`` (e.g. ``"prelude.c"``)."""
    return files("controllers.export").joinpath("runtime").joinpath(name).read_bytes() \
        .decode("utf-8")


def template(name: str) -> Template:
    """The runtime file ``name`` (e.g. ``"header.h"``) as a template of ``${field}`` fields."""
    return Template(runtime(name))
