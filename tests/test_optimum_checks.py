"""``experiments.stats.checks.optimum_checks``: what must hold where rows report fits at their
optimum (the lambda = 0 bound, the mean data cost, no converged fit beaten by another start), on
rows built by hand so that each check can be made to fail."""

from __future__ import annotations

import pytest

from experiments.table import Row
from experiments.stats.checks import optimum_checks

RTOL = 1e-3


def _fit(seed, objective, data, starts, stop="converged"):
    return {"seed": seed, "stop": stop, "objective": objective, "data_cost": data,
            "reg_cost": objective - data, "iterations": 10, "agree": 1, "spread": 0.0,
            "multiple_optima": False, "start_rtol": RTOL,
            "starts": [{"start": f"s{i}", "cost": c, "stop": "converged", "iterations": 10,
                        "reused": False} for i, c in enumerate(starts)]}


def _row(lam, fits, starts=("draw", "lip", "exchange")):
    settings = {"training": "simultaneous", "hidden": 8, "lambda": lam, "weight_decay": 1e-5,
                "continuation_lambda": 0.01, "starts": list(starts)}
    data = [f["data_cost"] for f in fits]
    return Row.from_json({
        "kind": "pgnn", "label": f"lambda={lam}", "lambda": lam, "hidden": 8,
        "n_seeds": len(fits), "settings": settings, "fits": fits,
        "data_cost": {"mean": sum(data) / len(data), "std": 0.0}})


def _checks(zero_fits, reg_fits, starts=("draw", "lip", "exchange")):
    rows = [_row(0.0, zero_fits, starts), _row(0.01, reg_fits, starts)]
    return {(c.check, c.a): c.to_json() for c in optimum_checks(rows)}


def test_every_check_holds_on_rows_at_their_optimum():
    zero = [_fit(0, 0.090, 0.086, [0.090, 0.095]), _fit(1, 0.093, 0.088, [0.093])]
    reg = [_fit(0, 0.091, 0.087, [0.091, 0.094]), _fit(1, 0.0935, 0.0885, [0.0935])]
    checks = _checks(zero, reg)
    assert all(c["passed"] and c["at_optimum"] for c in checks.values())
    assert len(checks) == 4  # bound, data cost, and one converged_beaten per row


def test_a_lambda_zero_fit_above_its_regularized_objective_fails_the_bound():
    zero = [_fit(0, 0.0967, 0.086, [0.0967]), _fit(1, 0.093, 0.088, [0.093])]
    reg = [_fit(0, 0.0933, 0.087, [0.0933]), _fit(1, 0.0935, 0.0885, [0.0935])]
    bound = _checks(zero, reg)[("bound", "lambda=0.0")]
    assert not bound["passed"] and bound["failing_seeds"] == [0]


def test_a_higher_mean_data_cost_at_lambda_zero_fails():
    zero = [_fit(0, 0.090, 0.089, [0.090])]
    reg = [_fit(0, 0.091, 0.087, [0.091])]
    assert not _checks(zero, reg)[("data_cost", "lambda=0.0")]["passed"]


@pytest.mark.parametrize("other,passed", [(0.08995, True), (0.0898, False)])
def test_a_converged_fit_beaten_by_another_start_beyond_the_tolerance_fails(other, passed):
    """A start lower than the kept fit by more than start_rtol (0.1 %) fails; within it, not."""
    zero = [_fit(0, 0.090, 0.086, [0.090, other])]
    reg = [_fit(0, 0.091, 0.087, [0.091])]
    assert _checks(zero, reg)[("converged_beaten", "lambda=0.0")]["passed"] is passed


def test_rows_of_one_start_are_listed_but_not_counted():
    """The paper's cost (one start, a fixed budget): its checks are printed as not at an
    optimum, and to_json's checks_passed ignores them."""
    zero = [_fit(0, 0.0967, 0.089, [0.0967])]
    reg = [_fit(0, 0.0933, 0.087, [0.0933])]
    checks = _checks(zero, reg, starts=("draw",))
    assert not checks[("bound", "lambda=0.0")]["passed"]
    assert not any(c["at_optimum"] for c in checks.values())
    doc = optimum_checks([_row(0.0, zero, ("draw",)), _row(0.01, reg, ("draw",))])
    assert all(not c.at_optimum for c in doc)
