"""``clm-sim compare`` says "reproduces" only for what it checked: a table it
cannot check is refused in one line (exit 2), the columns it skipped are listed, and the
``force rms`` columns of a ``data:`` table are compared."""

from __future__ import annotations

import json

import pytest

from experiments.cli import main

HEAD = "| feedforward | seeds | MAE r1 [µm] | m [kg] |\n|---|---|---|---|\n"
ROW = {"label": "LIP", "n_seeds": 1, "mae": {"r1": {"mean": 1.5e-6, "std": 0.0}},
       "theta_phy": {"mass": 18.8}, "theta_phy_per_seed": [{"mass": 18.8}]}


def _compare(tmp_path, capsys, page: str, rows: list | str):
    (tmp_path / "expected.md").write_text(page)
    fresh = rows if isinstance(rows, str) else json.dumps({"rows": rows})
    (tmp_path / "table.json").write_text(fresh)
    code = main(["compare", str(tmp_path / "expected.md"), str(tmp_path / "table.json")])
    captured = capsys.readouterr()
    return code, captured.out.strip().splitlines(), captured.err.strip().splitlines()


def test_a_matching_table_reproduces(tmp_path, capsys):
    code, out, err = _compare(tmp_path, capsys, HEAD + "| LIP | 1 | 1.500 | 18.80 |\n", [ROW])
    assert code == 0 and err == [] and "reproduces" in out[-1], (out, err)


@pytest.mark.parametrize("case, page, rows, expected", [
    ("unparsable cell", HEAD + "| LIP | 1 | 1.5x | 18.80 |\n", [ROW], "cannot read '1.5x'"),
    ("mae null", HEAD + "| LIP | 1 | 1.500 | 18.80 |\n",
     [{**ROW, "mae": {"r1": {"mean": None, "std": 0.0}}}], "no number for it"),
    ("mae key missing", HEAD + "| LIP | 1 | 1.500 | 18.80 |\n",
     [{k: v for k, v in ROW.items() if k != "mae"}], "no number for it"),
    ("seeds not a number", HEAD + "| LIP | one | 1.500 | 18.80 |\n", [ROW], "seeds"),
    ("empty table", HEAD, [ROW], "no rows"),
    ("lower-case headers only", "| feedforward | seeds | mae r1 [µm] |\n|---|---|---|\n"
     "| LIP | 1 | 1.500 |\n", [ROW], "no column clm-sim compares"),
    ("row without a label", HEAD + "| LIP | 1 | 1.500 | 18.80 |\n", [{"n_seeds": 1}], "label"),
    ("NaN in the fresh table", HEAD + "| LIP | 1 | 1.500 | 18.80 |\n",
     json.dumps({"rows": [ROW]}).replace("18.8", "NaN"), "cannot read it"),
    ("deep JSON", HEAD, "[" * 100_000 + "]" * 100_000, "nested too deeply"),
])
def test_a_table_it_cannot_check_is_refused(tmp_path, capsys, case, page, rows, expected):
    code, out, err = _compare(tmp_path, capsys, page, rows)
    assert code == 2 and out == [] and len(err) == 1 and expected in err[0], (out, err)


def test_skipped_columns_are_listed_and_not_passed_off_as_checked(tmp_path, capsys):
    """A lower-case ``mae r1`` beside a checked column: listed as not compared; the verdict
    says it holds only in the columns compared."""
    page = ("| feedforward | seeds | mae r1 [µm] | m [kg] |\n|---|---|---|---|\n"
            "| LIP | 1 | 150.0 | 18.80 |\n")
    code, out, err = _compare(tmp_path, capsys, page, [ROW])
    assert code == 0 and any("not compared" in line and "mae r1" in line for line in out)
    assert "in the columns it compares" in out[-1]


DATA_HEAD = ("| feedforward | seeds | force rms training inside [N] | m [kg] |\n"
             "|---|---|---|---|\n")


@pytest.mark.parametrize("fresh_mean, code", [(2.5, 0), (250.0, 1)])
def test_force_rms_columns_of_a_data_table_are_compared(tmp_path, capsys, fresh_mean, code):
    row = {"label": "PGNN", "n_seeds": 3, "converged": 3,
           "force_rms": {"training": {"inside": {"mean": fresh_mean, "std": 0.1,
                                                 "median": fresh_mean}}},
           "theta_phy": {"mass": 18.8}, "theta_phy_per_seed": [{"mass": 18.8}] * 3}
    page = DATA_HEAD + "| PGNN | 3 | 2.500 ± 0.100 (median 2.500) | 18.80 |\n"
    got, out, err = _compare(tmp_path, capsys, page, [row])
    assert got == code, (out, err)
    if code:
        assert any("force rms training inside" in line for line in out), out


@pytest.mark.parametrize("case, head, cell, expected", [
    ("MAE in nm", "| feedforward | seeds | MAE r1 [nm] |", "1500.0", "'MAE r1 [nm]'"),
    ("MAE in mm", "| feedforward | seeds | MAE r1 [mm] |", "0.0015", "'MAE r1 [mm]'"),
    ("MAE without a unit", "| feedforward | seeds | MAE r1 |", "1.500", "'MAE r1'"),
    ("mass in g", "| feedforward | seeds | m [g] |", "18.80", "'m [g]'"),
    ("mass in N", "| feedforward | seeds | m [N] |", "18.80", "'m [N]'"),
])
def test_a_column_in_another_unit_is_refused(tmp_path, capsys, case, head, cell, expected):
    """The unit in a header is what the fresh table means by its numbers: a page in nm, mm or
    g would otherwise be compared as µm and kg (and 'reproduce' a table 1000 times off)."""
    page = head + "\n|---|---|---|\n| LIP | 1 | " + cell + " |\n"
    code, out, err = _compare(tmp_path, capsys, page, [ROW])
    assert code == 2 and out == [] and len(err) == 1, (out, err)
    assert expected in err[0] and "unit" in err[0], err


def test_a_column_given_twice_is_refused(tmp_path, capsys):
    page = ("| feedforward | seeds | MAE r1 [µm] | MAE r1 [µm] |\n|---|---|---|---|\n"
            "| LIP | 1 | 1.500 | 99 |\n")
    code, out, err = _compare(tmp_path, capsys, page, [ROW])
    assert code == 2 and out == [] and len(err) == 1, (out, err)
    assert "'MAE r1 [µm]'" in err[0] and "twice" in err[0], err


def test_a_row_in_one_table_only_is_named_without_nan(tmp_path, capsys):
    page = HEAD + "| LIP | 1 | 1.500 | 18.80 |\n| PGNN magic | 1 | 0.1 | – |\n"
    other = {**ROW, "label": "feedback only"}
    code, out, err = _compare(tmp_path, capsys, page, [ROW, other])
    assert code == 1, (out, err)
    assert not any("nan" in line for line in out), out
    assert any("PGNN magic" in line and "not in the fresh table" in line for line in out), out
    assert any("feedback only" in line and "not in the expected table" in line
               for line in out), out
    # and the count says rows, not cells outside the tolerance
    assert out[-1] == "2 row(s) in one table only (a table of another config?)", out


@pytest.mark.parametrize("page_cell,fresh_converged,fresh_edge,code", [
    ("6/10 ⚠", 5, 0, 0), ("6/10 ⚠", 4, 0, 1), ("6/10 ⚠", 3, 2, 0), ("6/10 ⚠", 2, 2, 1),
    ("6/10 (3 at the edge) ⚠", 2, 0, 0)])
def test_fits_at_the_edge_widen_the_converged_count_tolerance(
        tmp_path, capsys, page_cell, fresh_converged, fresh_edge, code):
    """One fit either way, and one more per fit at the edge in either run."""
    row = {"kind": "pgnn", "label": "P", "n_seeds": 10, "hidden": 8,
           "mae": {"r1": {"mean": 1e-6, "std": 1e-7}},
           "theta_phy": {"mass": 1.0, "viscous": 1.0, "coulomb": 1.0, "stiffness": 1.0},
           "fits": [{"seed": s, "stop": "converged"} for s in range(10)],
           "converged": fresh_converged, "at_edge": fresh_edge}
    (tmp_path / "fresh.json").write_text(json.dumps({"rows": [row]}))
    (tmp_path / "page.md").write_text(
        "| feedforward | seeds | MAE r1 [µm] | fits converged |\n|---|---|---|---|\n"
        f"| P | 10 | 1.000 ± 0.100 | {page_cell} |\n")
    assert main(["compare", str(tmp_path / "page.md"), str(tmp_path / "fresh.json")]) == code
    capsys.readouterr()
