"""Config errors through the CLI: exit code 2, one line naming the file and the key, no output."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from experiments.cli import main
from experiments.config import ExperimentConfig, load_config, resolved

# name: (YAML text or None for a missing file, text the one-line message must contain)
BAD_CONFIGS = {
    "unknown top-level key": ("name: x\nsede: 3\n", "sede"),
    "unknown nested key": ("plant:\n  mas: 18.8\n", "plant.mas"),
    "wrong type": ("plant:\n  mass: heavy\n", "plant.mass"),
    "negative mass": ("plant:\n  mass: -1.0\n", "mass"),
    "negative encoder resolution": ("plant:\n  encoder_resolution: -1.0e-7\n",
                                    "encoder_resolution"),
    "unknown effect type": ("plant:\n  effects:\n    - type: magnetism\n", "magnetism"),
    "effect without type": ("plant:\n  effects:\n    - amplitude: 1.0\n", "plant.effects[0]"),
    "bad effect parameter": ("plant:\n  effects:\n    - {type: cogging, period: -1.0}\n",
                             "period"),
    "unknown effect parameter": ("plant:\n  effects:\n    - {type: cogging, amplitud: 1.0}\n",
                                 "amplitud"),
    "missing file": (None, "not found"),
    "invalid YAML": ("plant: [1, 2\n", "invalid YAML"),
    "not a mapping": ("- r1\n- r2\n", "mapping"),
    "undefined training reference": ("training:\n  reference: r3\n", "training.reference"),
    "undefined replay reference": ("replay: [r1, r9]\n", "replay[1]"),
    "lambda on kind lip": ("feedforwards:\n  - kind: lip\n    lambda: 0.1\n", "lambda"),
    "unknown feedforward kind": ("feedforwards:\n  - kind: magic\n", "feedforwards[0].kind"),
    "negative sample time": ("ts: -1.0e-4\n", "ts"),
    "seed not an integer": ("seed: 1.5\n", "seed"),
    "list expected": ("replay: r1\n", "replay"),
    "negative dither": ("training:\n  dither:\n    std_n: -5.0\n", "std_n"),
    "bad reference bound": ("references:\n  r1:\n    points_m: [0.0, 0.1]\n"
                            "    max_velocity: -1.0\n", "max_velocity"),
}


def _run_cli(args, capsys) -> tuple[int, list[str]]:
    code = main(args)
    return code, capsys.readouterr().err.strip().splitlines()


@pytest.mark.parametrize("case", list(BAD_CONFIGS))
def test_config_error_is_one_line_exit_2_no_output(case, tmp_path, capsys):
    text, key = BAD_CONFIGS[case]
    cfg = tmp_path / "bad.yaml"
    if text is not None:
        cfg.write_text(text)
    out = tmp_path / "out"
    code, lines = _run_cli(["run", str(cfg), "--out", str(out), "--quiet"], capsys)
    assert code == 2
    assert len(lines) == 1, lines
    assert lines[0].startswith("clm-sim: error: ")
    assert str(cfg) in lines[0]
    assert key in lines[0]
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == (["bad.yaml"] if text else [])


def test_unstable_design_is_refused_without_partial_results(tmp_path, capsys):
    """Found only after the run started (PID design): still one line and nothing left behind."""
    cfg = tmp_path / "hot.yaml"
    cfg.write_text("controller:\n  crossover_hz: 3000.0\n")
    out = tmp_path / "out"
    code, lines = _run_cli(["run", str(cfg), "--out", str(out), "--quiet"], capsys)
    assert code == 2
    assert len(lines) == 1 and lines[0].startswith("clm-sim: error: ")
    assert "unstable" in lines[0] and "crossover" in lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["hot.yaml"]


def test_run_refuses_to_overwrite_a_foreign_folder(tmp_path, capsys):
    cfg = tmp_path / "ok.yaml"
    cfg.write_text("name: ok\n")
    out = tmp_path / "mine"
    out.mkdir()
    (out / "thesis.tex").write_text("precious")
    code, lines = _run_cli(["run", str(cfg), "--out", str(out), "--quiet"], capsys)
    assert code == 2 and len(lines) == 1 and str(out) in lines[0]
    assert [p.name for p in out.iterdir()] == ["thesis.tex"]


def test_shipped_config_loads_and_resolves(tmp_path):
    """The baseline config, and its resolved form re-read as a config, give the same object."""
    shipped = Path(__file__).resolve().parents[1] / "experiments" / "configs" / "lip_baseline.yaml"
    config = load_config(shipped)
    assert [f.kind for f in config.feedforwards] == ["none", "lip"]
    again = tmp_path / "resolved.yaml"
    again.write_text(yaml.safe_dump(resolved(config), sort_keys=False))
    assert load_config(again) == config


def test_defaults_are_the_papers_plant():
    p = ExperimentConfig().plant
    assert (p.mass, p.viscous, p.coulomb, p.stiffness) == (18.8, 172.0, 7.21, 0.0)


def test_a_missing_required_key_is_named_as_the_file_names_it():
    """A required field with a config alias (lam <- lambda) is named by the alias: the file's
    key, not the Python name the user never wrote."""
    import dataclasses

    from clm_sim.errors import UserError
    from clm_sim.schema import build

    @dataclasses.dataclass
    class Pull:
        lam: float

    Pull.aliases = {"lambda": "lam"}  # config -> field, as the settings classes declare it

    with pytest.raises(UserError, match=r"^pull\.lambda: missing; Pull needs lambda$"):
        build(Pull, {}, "pull")
