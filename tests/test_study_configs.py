"""Study configs read strictly: a section of an experiment config that no study reads
(``feedforwards:``, ``replay:``, ``data:``) is refused in one line naming it, as ``truth:`` is; an
"outside" reference that is the inside one is refused; a config that names two studies without
``kind:`` is told which two. The studies never run here: each test replaces them by a stub that
fails if it is reached."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from experiments.cli import main

CONFIGS = Path(__file__).resolve().parents[1] / "experiments" / "configs"
# kind -> (shipped config, the module of its loader, the loader)
STUDIES = {
    "mechanism": ("lambda0_mechanism.yaml", "mechanism.settings", "load_mechanism"),
    "failure_map": ("failure_map.yaml", "failure_map.study", "load_failure_map"),
    "identifiability": ("identifiability.yaml", "profiles.study", "load_profiles"),
    "extrapolation": ("extrapolation_study.yaml", "extrapolation.study", "load_study"),
}


def _module(kind: str):
    import importlib

    return importlib.import_module(f"experiments.studies.{STUDIES[kind][1]}")


@pytest.fixture(autouse=True)
def no_study_runs(monkeypatch):
    """The runner checks the output folder after the config is read and before any work:
    reaching it means the config was not refused."""
    import clm_sim.outdir

    def ran(*args, **kwargs):
        raise AssertionError("the study ran: its config was not refused")

    monkeypatch.setattr(clm_sim.outdir, "check_output_folder", ran)


def _write(tmp_path, kind: str, edit=None) -> Path:
    data = yaml.safe_load((CONFIGS / STUDIES[kind][0]).read_text())
    if edit:
        edit(data)
    path = tmp_path / "study.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _refused(path: Path, tmp_path, capsys, *expected) -> str:
    before = sorted(p.name for p in tmp_path.iterdir())
    code = main(["study", str(path), "--out", str(tmp_path / "out"), "--quiet"])
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert code == 2 and len(lines) == 1, captured.err
    assert lines[0].startswith(f"clm-sim: error: {path}: "), lines[0]
    for text in expected:
        assert text in lines[0], lines[0]
    assert captured.out == ""
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    return lines[0]


@pytest.mark.parametrize("kind", list(STUDIES))
def test_the_shipped_study_configs_load(kind, tmp_path):
    """The base of every edit below: without it, the config is accepted."""
    config, settings = getattr(_module(kind), STUDIES[kind][2])(_write(tmp_path, kind))
    assert config.data is None


SECTIONS = {
    "feedforwards": [{"kind": "pgnn", "training": "simultaneous", "lambda": 0.5, "hidden": 64,
                      "seeds": 9}],
    "replay": ["r1"],
    "data": {"training": "rec.npz"},
}


@pytest.mark.parametrize("section", list(SECTIONS))
@pytest.mark.parametrize("kind", list(STUDIES))
def test_a_section_no_study_reads_is_refused(kind, section, tmp_path, capsys):
    path = _write(tmp_path, kind, lambda d: d.update({section: SECTIONS[section]}))
    _refused(path, tmp_path, capsys, f"{section}: not used by the {kind} study")


@pytest.mark.parametrize("kind, edit", [
    ("failure_map", lambda d: d["failure_map"].update(outside={"position": "r1"})),
    ("extrapolation", lambda d: d["study"].update(outside=["r1"])),
    ("extrapolation", lambda d: d["study"].update(outside=["r2", "r1"])),
    ("mechanism", lambda d: d["mechanism"].update(outside="r1")),
])
def test_an_outside_reference_that_is_the_inside_one_is_refused(kind, edit, tmp_path, capsys):
    _refused(_write(tmp_path, kind, edit), tmp_path, capsys, "outside", "'r1'",
             "the inside reference")


def test_two_study_sections_without_kind_are_named(tmp_path, capsys):
    def edit(d):
        d.pop("kind")
        d["study"] = {"seeds": 2}

    line = _refused(_write(tmp_path, "mechanism", edit), tmp_path, capsys, "kind: missing",
                    "'study:' and 'mechanism:'", "kind: extrapolation", "kind: mechanism")
    assert "failure_map" not in line
