"""Run records: NPZ / CSV / MAT round trips, renamed and scaled columns."""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.io

from clm_sim.errors import UserError
from clm_sim.records.read import load_record
from clm_sim.records.write import save_csv, save_mat, save_npz
from clm_sim.run import SIGNALS, Run

META = {"run": "training", "seed": 11, "config": {"plant": {"mass": 18.8}}, "versions": {"x": "1"}}


@pytest.fixture(scope="module")
def short_run(default_training_run):
    """3000 samples of a simulated run (every signal known), with a meta dict."""
    r = default_training_run.slice(1000, 4000)
    return Run(**r.signals(), meta=META)


@pytest.fixture(scope="module")
def measured_run(short_run):
    """A measured record: true position and dither unknown (NaN)."""
    s = short_run.signals()
    return Run(t=s["t"], r=s["r"], y=s["y"], u=s["u"], u_fb=s["u_fb"], u_ff=s["u_ff"], meta=META)


SAVERS = {"npz": save_npz, "csv": save_csv, "mat": save_mat}


@pytest.mark.parametrize("fmt", list(SAVERS))
@pytest.mark.parametrize("which", ["short_run", "measured_run"])
def test_round_trip_keeps_every_signal(fmt, which, request, tmp_path):
    run = request.getfixturevalue(which)
    path = tmp_path / f"run.{fmt}"
    SAVERS[fmt](run, path)
    back = load_record(path)
    assert len(back) == len(run)
    for name in SIGNALS:
        want, got = getattr(run, name), getattr(back, name)
        assert got.dtype == np.float64 and got.shape == want.shape, name
        np.testing.assert_array_equal(np.isnan(got), np.isnan(want), err_msg=name)
        if fmt == "csv":
            # Written with %.17g, which round-trips float64 (17 significant digits); the
            # tolerance is one unit of the 16th digit in case a parser rounds differently.
            np.testing.assert_allclose(got, want, rtol=1e-15, atol=0, err_msg=name)
        else:
            np.testing.assert_array_equal(got, want, err_msg=name)  # binary float64: exact
    assert back.ts == pytest.approx(run.ts, rel=1e-12)


def test_npz_keeps_meta(short_run, tmp_path):
    path = tmp_path / "run.npz"
    save_npz(short_run, path)
    meta = load_record(path).meta
    assert {k: meta[k] for k in META} == META
    assert meta["source"] == str(path)


def test_csv_writes_meta_sidecar(short_run, tmp_path):
    path = tmp_path / "run.csv"
    save_csv(short_run, path)
    assert json.loads((tmp_path / "run.csv.meta.json").read_text()) == META
    assert path.read_text().splitlines()[0] == ",".join(SIGNALS)


def test_columns_are_renamed_and_scaled(short_run, tmp_path):
    """A foreign file: position as 'qm', force in volts 'vir' with the amplifier gain inside."""
    gain = 35.15  # N/V
    path = tmp_path / "measured.mat"
    scipy.io.savemat(path, {"t": short_run.t[:, None], "r": short_run.r[:, None],
                            "qm": short_run.y[:, None], "vir": (short_run.u / gain)[:, None],
                            "gtau": gain})
    back = load_record(path, columns={"y": "qm", "u": "vir"}, scale={"u": "gtau"})
    np.testing.assert_array_equal(back.y, short_run.y)
    # Division then multiplication by the gain: one rounding each, <= 2 ulp relative.
    np.testing.assert_allclose(back.u, short_run.u, rtol=5e-16 * 2, atol=0)
    assert np.all(np.isnan(back.y_true))
    back = load_record(path, columns={"y": "qm", "u": "vir"}, scale={"u": gain})
    np.testing.assert_allclose(back.u, short_run.u, rtol=5e-16 * 2, atol=0)


def test_slice_keeps_meta_and_lengths(short_run):
    part = short_run.slice(10, 110)
    assert len(part) == 100 and part.meta == short_run.meta
    np.testing.assert_array_equal(part.u, short_run.u[10:110])


def test_run_refuses_ragged_signals():
    with pytest.raises(ValueError, match="length"):
        Run(t=np.arange(10.0), r=np.zeros(10), y=np.zeros(10), u=np.zeros(9))


def _csv(tmp_path, header: str, n: int = 600):
    t = np.arange(n) * 1e-3
    cols = {"t": t, "r": np.sin(t), "y": np.sin(t) + 1e-6, "u": np.cos(t), "qm": np.sin(2 * t)}
    names = [h.strip() for h in header.split(",")]
    data = np.column_stack([cols.get(nm, 0.5 * t) for nm in names])
    path = tmp_path / "rec.csv"
    np.savetxt(path, data, delimiter=",", header=header, comments="")
    return path


@pytest.mark.parametrize("header", ["t,r,y,u,u", "t,r,y,u,y", "t,t,r,y,u", "t,r, y,y,u",
                                    "t,r,y,u,qm,qm"])
def test_a_column_name_twice_is_refused(header, tmp_path):
    """A dict of columns keeps the last of two namesakes: a mass twice the true one, said
    nowhere. The header's duplicate is refused by name."""
    with pytest.raises(UserError, match="twice"):
        load_record(_csv(tmp_path, header))


@pytest.mark.parametrize("columns", [{"r": "qm", "y": "qm"}, {"r": "y"}, {"u": "t"},
                                     {"y": "r"}, {"e": "y"}, {"u_ff": "u"}])
def test_two_signals_on_one_column_are_refused(columns, tmp_path):
    """y read as r too makes the tracking error zero; the mapping is refused."""
    with pytest.raises(UserError, match="both be read from column"):
        load_record(_csv(tmp_path, "t,r,y,u,qm"), columns=columns)


def test_a_column_mapped_away_frees_its_name(tmp_path):
    run = load_record(_csv(tmp_path, "t,r,y,u,qm"), columns={"y": "qm"})
    assert np.allclose(run.y, np.sin(2 * run.t))
