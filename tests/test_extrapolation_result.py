"""The extrapolation study's typed result: ``study.json`` reads back into the same value, and its
keys live only in the result module (the study, the report and the figures read fields)."""

from __future__ import annotations

import ast
import json
from pathlib import Path

import pytest

from clm_sim.features import TrainingRange
from experiments.studies.extrapolation.result import (
    FEEDBACK, LIP, SEQUENTIAL, Costs, ExtrapolationResult, NetworkParts, Spread, Trained,
    Variant, variant_key, variant_label)

ROOT = Path(__file__).resolve().parents[1]
STUDIES = ROOT / "experiments" / "studies" / "extrapolation"

# Keys of study.json that only a typed field would otherwise carry between modules.
JSON_KEYS = {"variants", "theta_lip", "lip_residual_rms_n", "ranges", "theta_phy",
             "theta_phy_per_seed", "parts", "per_seed", "network_max_abs_n", "network_rms_n",
             "network_max_abs_beyond_n", "network_max_abs_within_n", "fraction_beyond",
             "model_error_beyond_rms_n", "iterations", "mae"}


def _result() -> ExtrapolationResult:
    theta = {"m": 1.5, "fv": 10.0, "fc": 2.0, "fk": -3.0}
    parts = {"r1": NetworkParts(1.0, 0.5, None, None, 0.0, None),
             "r2": NetworkParts(2.0, 0.7, 3.0, 1.0, 0.25, 0.4)}
    trained = Trained((theta, {**theta, "m": 1.6}), {**theta, "m": 1.55}, Costs(0.1, 0.002),
                      (7, 9), parts)
    mae = {"r1": Spread(1e-6, 1e-7, (0.9e-6, 1.1e-6)), "r2": Spread(2e-6, 0.0, (2e-6, 2e-6))}
    variants = {SEQUENTIAL: Variant(mae, trained), variant_key(0.0): Variant(mae, trained),
                variant_key(0.01): Variant(mae, trained),
                FEEDBACK: Variant({r: Spread(5e-6, 0.0, (5e-6,)) for r in mae}),
                LIP: Variant({r: Spread(3e-6, 0.0, (3e-6,)) for r in mae},
                             lip_error_beyond_rms_n={"r2": 0.3})}
    return ExtrapolationResult((0.0, 0.01), 0.01, 4, 2, "r1", ("r2",), theta, 0.05,
                               {"r1": TrainingRange(0.01, 0.1, 1.0),
                                "r2": TrainingRange(0.02, 0.1, 1.0)}, variants)


def test_json_reads_back_into_the_same_result():
    result = _result()
    text = json.dumps(result.to_json(), indent=1)
    back = ExtrapolationResult.from_json(json.loads(text))
    assert back == result
    assert json.dumps(back.to_json(), indent=1) == text


def test_json_keeps_the_file_format():
    d = _result().to_json()
    assert list(d["variants"]) == ["sequential", "lambda=0", "lambda=0.01", "feedback only", "LIP"]
    assert set(d["variants"]["LIP"]) == {"mae", "model_error_beyond_rms_n"}
    assert set(d["variants"]["feedback only"]) == {"mae"}
    assert d["variants"]["lambda=0"]["cost"] == {"data": 0.1, "deviation": 0.002}
    assert d["ranges"]["r2"] == {"position_m": 0.02, "velocity_m_s": 0.1,
                                 "acceleration_m_s2": 1.0}


def test_named_variants():
    result = _result()
    assert result.unregularized is result.variants["lambda=0"]
    assert result.regularized is result.variants["lambda=0.01"]
    assert result.lam_keys == ["lambda=0", "lambda=0.01"]
    assert result.references == ("r1", "r2")
    assert variant_label(variant_key(1e-4)) == "λ = 0.0001"


def _string_constants(path: Path) -> set[tuple[str, int]]:
    """Non-docstring string constants (f-string parts included) of a module, with lines."""
    tree = ast.parse(path.read_text(), str(path))
    docstrings = {id(node.body[0].value) for node in ast.walk(tree)
                  if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef))
                  and node.body and isinstance(node.body[0], ast.Expr)
                  and isinstance(node.body[0].value, ast.Constant)}
    return {(node.value, node.lineno) for node in ast.walk(tree)
            if isinstance(node, ast.Constant) and isinstance(node.value, str)
            and id(node) not in docstrings}


@pytest.mark.parametrize("module", ["study.py", "figures.py"])
def test_study_and_figures_use_no_json_key(module):
    hits = {(s, line) for s, line in _string_constants(STUDIES / module)
            if s in JSON_KEYS or s.startswith("lambda=")}
    assert hits == set()


def test_the_scan_sees_the_keys_in_the_result_module():
    found = {s for s, _ in _string_constants(STUDIES / "result.py")}
    assert JSON_KEYS <= found and "lambda=" in found
