"""The failure map of finding (iii): statistics against scipy, strict config, and a tiny grid end
to end through ``clm-sim study`` whose report must state what its JSON says."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from build_once import build_once
from scipy import stats

from clm_sim.errors import UserError
from experiments.cli import main as cli
from experiments.stats.paired import LogRatio, holm
from experiments.studies.failure_map.study import load_failure_map, verdict

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "experiments" / "configs" / "failure_map.yaml"


# --------------------------------------------------------------------------------------------
# statistics: independent oracles
# --------------------------------------------------------------------------------------------

def test_paired_log_ratio_matches_scipy_paired_t():
    rng = np.random.default_rng(3)
    b = rng.uniform(0.3, 0.8, 10)
    a = b * np.exp(rng.normal(0.2, 0.15, 10))
    got = LogRatio.of(a, b, 0.9)
    ref = stats.ttest_rel(np.log(a), np.log(b))
    ci = ref.confidence_interval(0.9)
    # Same t statistic computed two ways: agreement to rounding.
    np.testing.assert_allclose([got.low, got.high], np.exp([ci.low, ci.high]), rtol=1e-12)
    np.testing.assert_allclose(got.p, ref.pvalue, rtol=1e-9)
    assert got.low < got.ratio < got.high
    assert verdict(got) == ("holds" if got.low > 1 else "undecided")


def test_holm_by_hand():
    # Sorted 0.01, 0.03, 0.04 -> 3*0.01, 2*0.03, max(0.06, 1*0.04); back in input order.
    np.testing.assert_allclose(holm([0.01, 0.04, 0.03]), [0.03, 0.06, 0.06], rtol=1e-12)
    assert holm([0.5, 0.9]) == [1.0, 1.0]


# --------------------------------------------------------------------------------------------
# the file's keys for the two fits are no contract between modules
# --------------------------------------------------------------------------------------------

def _json_key_uses() -> set[tuple[str, int]]:
    """(file, line) of every string literal (docstrings aside) in the packages that is one of
    failure_map.json's names for the two fits of a cell, or contains "lam0"."""
    import ast

    hits = set()
    for package in ("clm_sim", "controllers", "experiments"):
        for path in sorted((ROOT / package).rglob("*.py")):
            tree = ast.parse(path.read_text(), str(path))
            docstrings = {id(node.body[0].value) for node in ast.walk(tree)
                          if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef,
                                               ast.AsyncFunctionDef))
                          and node.body and isinstance(node.body[0], ast.Expr)
                          and isinstance(node.body[0].value, ast.Constant)}
            for node in ast.walk(tree):
                if (isinstance(node, ast.Constant) and isinstance(node.value, str)
                        and id(node) not in docstrings
                        and (node.value in ("lam0", "reg") or "lam0" in node.value)):
                    hits.add((path.relative_to(ROOT).as_posix(), node.lineno))
    return hits


def test_lam0_and_reg_appear_only_in_the_json_mapping():
    import ast

    module = ROOT / "experiments" / "studies" / "failure_map" / "result.py"
    mapping = next(node.lineno for node in ast.parse(module.read_text()).body
                   if isinstance(node, ast.Assign) and node.targets[0].id == "_JSON_KEYS")
    # The scan finds the mapping itself (so it can find a use), and nothing else: the report,
    # the figures and the study read typed fields, never the file's keys.
    assert _json_key_uses() == {("experiments/studies/failure_map/result.py", mapping)}


# --------------------------------------------------------------------------------------------
# config: strict, names the key
# --------------------------------------------------------------------------------------------

def test_shipped_config_loads_with_five_cases_and_two_directions():
    _config, settings = load_failure_map(SHIPPED)
    assert list(settings.cases) == ["none", "cable_carrier", "cogging", "force_ripple",
                                    "stribeck"]
    assert settings.cases["none"] == ()
    assert settings.outside == {"position": "r2", "velocity": "r3"}
    assert settings.seeds >= 10 and settings.lam == 0.01


def _write(tmp_path, edit) -> Path:
    data = yaml.safe_load(SHIPPED.read_text())
    edit(data)
    path = tmp_path / "fm.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


@pytest.mark.parametrize("edit, words", [
    (lambda d: d["failure_map"].update(seed=3), ["failure_map.seed", "unknown key"]),
    (lambda d: d["failure_map"].update(seeds=1), ["seeds", ">= 2"]),
    (lambda d: d["failure_map"].update({"lambda": 0}), ["lambda", "> 0"]),
    (lambda d: d["failure_map"]["outside"].update(position="r9"), ["'r9'", "not defined"]),
    (lambda d: d["failure_map"]["cases"].update(bad=[{"type": "cogging", "amplitud": 1}]),
     ["cases.bad[0].amplitud", "unknown key"]),
    (lambda d: d.update(plant={"effects": []}), ["plant.effects", "per case"]),
])
def test_bad_config_is_one_error_naming_the_key(tmp_path, edit, words):
    path = _write(tmp_path, edit)
    with pytest.raises(UserError) as info:
        load_failure_map(path)
    assert str(info.value).startswith(str(path))
    for word in words:
        assert word in str(info.value)


# --------------------------------------------------------------------------------------------
# a tiny grid end to end
# --------------------------------------------------------------------------------------------

def _tiny(data):
    # One pass of r1 for training, a 4-neuron network, a short fit: about a second per cell.
    data["training"] = {"repeats": 1}
    # The shipped references at a fifth of their strokes and dwells, at the same speeds: r2
    # still leaves r1's range in position and r3 in velocity, in a fifth of the samples.
    for ref in data["references"].values():
        ref.update(points_m=[0.2 * p for p in ref["points_m"]], dwell_s=0.2 * ref["dwell_s"])
    fm = data["failure_map"]
    fm.update(seeds=3, hidden=[4], pgnn={"max_iter": 15, "decimation": 40})
    fm["cases"] = {k: fm["cases"][k] for k in ("none", "cable_carrier")}


def _run_tiny(folder: Path) -> dict:
    path = _write(folder, _tiny)
    out = folder / "out"
    code = cli(["study", str(path), "--out", str(out), "--quiet", "--workers", "2"])
    return {"code": code, "out": str(out), "config": str(path)}


@pytest.fixture(scope="session")
def tiny(tmp_path_factory):
    """The tiny study, run once for the session (once over xdist's workers: it reads only)."""
    built = build_once(tmp_path_factory, "failure_map", _run_tiny)
    out = Path(built["out"])
    return built["code"], out, json.loads((out / "failure_map.json").read_text()), \
        (out / "report.md").read_text(), Path(built["config"])


@pytest.mark.slow
def test_tiny_grid_runs_and_every_cell_is_paired(tiny):
    code, out, s, _, _ = tiny
    assert code == 0 and not s["failures"]
    outside = [c for c in s["cells"] if c["direction"] != "inside"]
    # 2 cases x 1 size x 2 directions, each with all 3 seeds paired.
    assert len(outside) == 4 and {c["direction"] for c in outside} == {"position", "velocity"}
    for c in s["cells"]:
        assert c["n_seeds"] == 3 and len(c["mae_lam0"]["per_seed"]) == 3
        a, b = np.log(c["mae_lam0"]["per_seed"]), np.log(c["mae_reg"]["per_seed"])
        ci = stats.ttest_rel(a, b).confidence_interval(0.95)
        # The interval in the JSON is the paired t-interval of its own per-seed numbers.
        np.testing.assert_allclose([c["ratio"]["low"], c["ratio"]["high"]],
                                   np.exp([ci.low, ci.high]), rtol=1e-9)
        ratio = LogRatio(**{k: v for k, v in c["ratio"].items() if k != "p_holm"})
        assert c["verdict"] == verdict(ratio)
    for figure in ("ratio", "mechanism", "drift"):
        assert (out / "figures" / f"{figure}.png").stat().st_size > 10_000


@pytest.mark.slow
def test_tiny_report_states_the_region_from_the_json(tiny):
    _, _, s, text, _ = tiny
    outside = [c for c in s["cells"] if c["direction"] != "inside"]
    for v in ("holds", "reversed", "undecided"):
        assert len(s["region"][v]) == sum(c["verdict"] == v for c in outside)
    k = len(s["region"]["holds"])
    assert (f"holds in {k} of {len(outside)} extrapolation cells" in text if k else
            f"holds in none of the {len(outside)} extrapolation cells" in text)
    for c in outside:
        r = c["ratio"]
        interval = f"{r['ratio']:.2f} [{r['low']:.2f}, {r['high']:.2f}]"
        row = next(line for line in text.splitlines() if line.startswith(
            f"| {c['direction']} ({c['reference']}) | {c['case']}"))
        assert interval in row and c["verdict"] in row
        if c["verdict"] == "holds":
            assert f"{c['direction']} ({c['reference']}) / {c['case']} / n_l={c['hidden']} " \
                   f"{interval}" in text


@pytest.mark.slow
def test_tiny_fits_record_how_they_stopped(tiny):
    _, _, s, text, _ = tiny
    assert len(s["fits"]) == 2 * 2 * 3  # two lambdas per cell of 2 cases x 3 seeds
    assert {f["lambda"] for f in s["fits"]} == {0.0, 0.01}
    capped = sum(f["stop"] == "max_iter" for f in s["fits"])
    open_ = sum(f["stop"] != "converged" for f in s["fits"])
    assert s["capped_fits"] == capped and s["unconverged_fits"] == open_
    assert sum(c["unconverged_fits"] for c in s["cells"] if c["direction"] == "inside") == open_
    assert (f"{open_} fits did not pass the convergence test" in text and
            f"{capped} of them stopped at the iteration cap" in text if open_ else
            "Every fit passed the convergence test" in text)


@pytest.mark.slow
def test_tiny_grid_does_not_depend_on_the_worker_count(tiny, tmp_path):
    from experiments.studies.failure_map.study import compute, summarize

    _, _, s, _, path = tiny
    config, settings = load_failure_map(path)
    inline = summarize(settings, compute(config, settings, workers=1)).to_json()
    # Each cell is single-threaded and seeded: the same bits in a worker and inline.
    assert json.dumps(inline["cells"]) == json.dumps(s["cells"])
    assert math.isfinite(inline["cells"][0]["ratio"]["ratio"])


@pytest.mark.slow
def test_tiny_json_reads_back_into_the_same_result_and_figures(tiny, tmp_path):
    from experiments.studies.failure_map.result import FailureMapResult
    from experiments.studies.failure_map.study import draw, report

    _, out, s, text, path = tiny
    result = FailureMapResult.from_json(s)
    _config, settings = load_failure_map(path)
    assert result.settings == settings
    # The file is the result's one mapping: written back, the same bytes; and the report and
    # figures drawn from the read-back result are those the run wrote.
    assert json.dumps(result.to_json(), indent=1) == (out / "failure_map.json").read_text()
    assert FailureMapResult.from_json(result.to_json()) == result
    assert report(result) == text
    draw(result, tmp_path)
    for figure in ("ratio", "mechanism", "drift"):
        assert (tmp_path / f"{figure}.png").read_bytes() == \
            (out / "figures" / f"{figure}.png").read_bytes()
    # The file's keys map to the right fits: "lam0" is lambda = 0, "reg" the regularized one.
    first = result.cells[0]
    assert first.mae.unregularized == tuple(s["cells"][0]["mae_lam0"]["per_seed"])
    assert first.mae.regularized == tuple(s["cells"][0]["mae_reg"]["per_seed"])
    assert {f.lam for f in result.fits if f.stop} == {0.0, settings.lam}
