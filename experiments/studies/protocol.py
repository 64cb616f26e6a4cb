"""What a study is: the one declaration :mod:`experiments.studies.runner` runs.

Each study package (a folder of ``experiments/studies/``) says in its ``kind.py`` which config
it reads, at no import cost: ``KIND`` (the config's ``kind:``), ``SECTION`` (the section its
settings go under) and ``study()``, which imports the study's module and returns its
:class:`Study`. The runner finds them by walking the packages of ``experiments.studies`` (a new
kind is a new package and touches no list); the layer test counts that walk as an edge to each
``kind`` module.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any


def _no_figures(result, folder: Path) -> None:
    """A study without figures."""


@dataclass(frozen=True)
class Study:
    """One study kind: how its config is read, what it computes and what it writes.

    kind / section: the config's ``kind:`` and the section of its settings; what: how the
    output folder is named in messages ("a clm-sim failure map"); settings: its settings type;
    load(path) -> (config, settings), every check made, errors naming the file and key (config:
    an experiment config, or the study's name where it reads no experiment);
    compute(config, settings, *, workers, progress) -> (result, scene): the result (a type with
    ``to_json``/``from_json``), and what its figures need beyond it (trained models, replays;
    None when the result suffices); result: that type; result_file: the JSON it is written to;
    report(result, settings) -> the Markdown of ``report.md``; figures(result, folder, scene)
    draws into ``folder``; resolved(config, settings) -> the ``config.resolved.yaml`` mapping;
    workers: the default number of processes when ``--workers`` is not given (a callable; None:
    the study runs in one process and takes no ``workers``); inputs(path, settings) -> the files
    the output folder must not contain; summary(result, out) -> what the terminal prints (None:
    the report's findings, :func:`experiments.report.screen.report_summary`); exit_code(result).
    """

    kind: str
    section: str
    what: str
    settings: type
    load: Callable[[Any], tuple[Any, Any]]
    compute: Callable[..., tuple[Any, Any]]
    result: type
    result_file: str
    report: Callable[[Any, Any], str]
    resolved: Callable[[Any, Any], dict]
    figures: Callable[[Any, Path, Any], None] = _no_figures
    workers: Callable[[], int] | None = None
    inputs: Callable[[Any, Any], tuple] = lambda path, settings: (path,)
    summary: Callable[[Any, Path], str] | None = None
    exit_code: Callable[[Any], int] = lambda result: 0
    json_options: tuple[tuple[str, Any], ...] = ()
