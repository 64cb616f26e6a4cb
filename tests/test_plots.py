"""The figures: what each panel shows, its units, its colours, and where the legend goes."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from clm_sim.run import Run
from experiments import plots
from experiments.diagnosis.figures import plot_origin_scan
from experiments.sweeps.figures import key_label, mae_vs_key_figure
from experiments.table import Row


def test_importing_plots_chooses_no_backend():
    """A notebook's inline backend must survive ``import experiments.plots``."""
    code = ("import sys, experiments.plots; "
            "print('matplotlib.pyplot' in sys.modules, 'MPLBACKEND' in __import__('os').environ)")
    env = {k: v for k, v in os.environ.items() if k != "MPLBACKEND"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, env=env).stdout.split()
    assert out == ["False", "False"]


def _run(e_um: np.ndarray, u_ff: np.ndarray) -> Run:
    t = np.arange(len(e_um)) * 1e-4
    r = 0.01 * np.sin(2 * np.pi * t)
    return Run(t=t, r=r, y=r - e_um * 1e-6, u=u_ff, u_ff=u_ff)


@pytest.fixture
def replays():
    """Feedback only with ±200 µm spikes, LIP and two PGNNs below 1 µm, on one reference."""
    n = 2000
    s = np.sin(np.linspace(0, 6, n))
    return {"feedback only": {"r1": _run(200 * s, np.zeros(n))},
            "LIP": {"r1": _run(0.7 * s, 10 * s)},
            "PGNN a": {"r1": _run(0.2 * s, 10 * s + 0.5)},
            "PGNN b": {"r1": _run(-0.4 * s, 10 * s - 0.3 * s)}}


def _line_colors(fig) -> list:
    return [ln.get_color() for ax in fig.axes for ln in ax.lines if ax.get_ylabel() != "r [mm]"]


def test_tracking_figure_gives_feedback_its_own_panel_and_feedforwards_one_scale(replays):
    fig = plots.tracking_figure(replays, "r1")
    ref, fb, *ff = fig.axes
    assert ref.get_ylabel() == "r [mm]" and fb.get_title(loc="left").startswith("feedback only")
    assert [ax.get_title(loc="left").split(":")[0] for ax in ff] == ["LIP", "PGNN a", "PGNN b"]
    limits = {ax.get_ylim() for ax in ff}
    assert len(limits) == 1  # one scale for every feedforward
    lo, hi = limits.pop()
    assert hi < 5 and lo > -5  # set by the feedforwards (< 1 µm), not by the ±200 µm spikes
    for ax in ff:  # and no curve is clipped
        y = ax.lines[0].get_ydata()
        assert lo <= y.min() and y.max() <= hi
    assert fb.get_ylim()[1] > 150
    colors = _line_colors(fig)
    assert len(set(colors)) == len(colors) == 4  # one distinct colour per feedforward
    assert all("[" in ax.get_ylabel() for ax in fig.axes)
    assert fig.axes[-1].get_xlabel() == "t [s]"


def test_feedforward_figure_shows_differences_from_the_lip(replays):
    fig = plots.feedforward_figure(replays, "r1")
    base, *diffs = fig.axes
    assert base.get_ylabel() == "u_ff [N]" and len(diffs) == 2
    assert all(ax.get_ylabel() == "Δu_ff [N]" for ax in diffs)
    lip = replays["LIP"]["r1"].u_ff
    np.testing.assert_allclose(diffs[0].lines[0].get_ydata(), 0.5, atol=1e-12)
    np.testing.assert_allclose(diffs[1].lines[0].get_ydata(),
                               replays["PGNN b"]["r1"].u_ff - lip, atol=1e-12)


def _typed(rows: list[dict]) -> list[Row]:
    return [Row.from_json(r) for r in rows]


def _sweep_rows():
    rows = []
    for res in (1e-8, 1e-7, 1e-6):
        for seed, noise in ((1, 0.9), (2, 1.1)):
            for pos, (kind, label, mae) in enumerate((("lip", "LIP", 4e-7),
                                                      ("none", "feedback only", 3e-6))):
                rows.append({"row": pos, "kind": kind, "training": None, "lambda": None,
                             "hidden": None, "label": label, "n_seeds": 1,
                             "mae": {"r1": {"mean": mae * noise * res / 1e-7, "std": 0.0},
                                     "r2": {"mean": mae * noise, "std": 0.0}},
                             "theta_phy": None, "plant.encoder_resolution": res, "seed": seed})
    return rows


def test_sweep_axes_have_readable_labels_units_and_the_legend_below():
    key = "plant.encoder_resolution"
    fig = mae_vs_key_figure(_typed(_sweep_rows()), [key, "seed"], key)
    assert [ax.get_xlabel() for ax in fig.axes] == ["encoder resolution q [µm]"] * 2
    assert [ax.get_ylabel() for ax in fig.axes] == ["MAE on r1 [µm]", "MAE on r2 [µm]"]
    np.testing.assert_allclose(fig.axes[0].lines[0].get_xdata(), [0.01, 0.1, 1.0])
    assert all(ax.get_legend() is None for ax in fig.axes) and len(fig.legends) == 1
    fig.canvas.draw()  # the legend lies below every panel, on none of the data
    legend = fig.legends[0].get_window_extent()
    assert all(legend.y1 <= ax.get_window_extent().y0 for ax in fig.axes)


@pytest.mark.parametrize("key, label, factor", [
    ("feedforwards[3].lambda", "regularization weight λ [–]", 1.0),
    ("controller.crossover_hz", "PID crossover frequency f_c [Hz]", 1.0),
    ("plant.encoder_resolution", "encoder resolution q [µm]", 1e6),
    ("training.repeats", "training repeats [–]", 1.0),
    ("plant.effects[0].amplitude", "plant.effects[0].amplitude [SI]", 1.0),  # unknown: as is
])
def test_key_labels(key, label, factor):
    assert key_label(key) == (label, factor)


def _lab(color: str) -> np.ndarray:
    """CIELAB (D65) of an sRGB colour: distances there follow what the eye tells apart."""
    from matplotlib.colors import to_rgb
    rgb = np.array(to_rgb(color))
    lin = np.where(rgb <= 0.04045, rgb / 12.92, ((rgb + 0.055) / 1.055) ** 2.4)
    xyz = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722],
                    [0.0193, 0.1192, 0.9505]]) @ lin / np.array([0.9505, 1.0, 1.089])
    f = np.where(xyz > (6 / 29) ** 3, np.cbrt(xyz), xyz / (3 * (6 / 29) ** 2) + 4 / 29)
    return np.array([116 * f[1] - 16, 500 * (f[0] - f[1]), 200 * (f[1] - f[2])])


def test_palette_colours_are_told_apart():
    # Delta E 25 is far above "just noticeable" (about 2); the teal #44AA99 beside Okabe-Ito's
    # bluish green was 18.6 and read as the same line in the study's theta figure.
    lab = [_lab(c) for c in plots.PALETTE]
    closest = min(np.linalg.norm(a - b) for i, a in enumerate(lab) for b in lab[i + 1:])
    assert closest > 25


def test_origin_scan_marks_the_registered_shift_in_mm():
    shifts = np.linspace(-1.25e-3, 1.25e-3, 65)
    rms = 2.5 - 0.2 * np.cos(2 * np.pi * (shifts + 0.672e-3) / 2.5e-3)
    ax = plot_origin_scan(-0.672e-3, shifts, rms)
    assert ax.get_xlabel() == "origin shift δ [mm]" and ax.get_ylabel() == "residual RMS [N]"
    marked = [ln.get_xdata()[0] for ln in ax.lines[1:]]
    assert marked == pytest.approx([0.0, -0.672])
    assert "-0.672 mm" in " ".join(t.get_text() for t in ax.get_legend().get_texts())


def _many_series_rows():
    """Seven feedforwards (LIP and six lambdas) over two network sizes, two seeds each."""
    rows = []
    for hidden in (8, 16):
        for seed in (1, 2):
            rows.append({"row": 0, "kind": "lip", "training": None, "lambda": None,
                         "hidden": None, "label": "LIP", "n_seeds": 1,
                         "mae": {"r1": {"mean": 4.1e-7, "std": 0.0}},
                         "theta_phy": None, "feedforwards[1].hidden": hidden, "seed": seed})
            for pos, lam in enumerate((0.0, 1e-4, 1e-3, 1e-2, 1e-1, 1.0), start=1):
                rows.append({"row": 1, "kind": "pgnn", "training": "simultaneous",
                             "lambda": lam, "hidden": hidden,
                             "label": f"PGNN simultaneous, lambda={lam:g}, n_l={hidden}",
                             "n_seeds": 1,
                             "mae": {"r1": {"mean": (2.5 + 0.1 * pos + 0.01 * seed) * 1e-7,
                                            "std": 0.0}},
                             "theta_phy": None, "feedforwards[1].hidden": hidden,
                             "feedforwards[1].lambda": lam, "seed": seed})
    return rows


def test_many_series_over_few_values_are_a_dot_plot_not_crossing_lines(tmp_path):
    swept = ["feedforwards[1].hidden", "feedforwards[1].lambda", "seed"]
    fig = mae_vs_key_figure(_typed(_many_series_rows()), swept, "feedforwards[1].hidden")
    ax = fig.axes[0]
    assert ax.get_xlabel() == "MAE on r1 [µm]"
    names = [t.get_text() for t in ax.get_yticklabels()]
    assert len(names) == 7 and any("LIP" in n for n in names)
    assert len(fig.legends) == 1 and len(fig.legends[0].get_texts()) == 2  # one per n_l
    plots.save(fig, tmp_path / "dots.png")


@pytest.mark.parametrize("name", ["$x^$", "$$", "$\\frac$", "a\x1fb", "r\tname"])
def test_a_name_from_a_file_is_drawn_as_written(name, tmp_path):
    """Row names and file names are text, never TeX: ``$x^$`` would stop matplotlib's drawing
    (an internal error) and a control character has no glyph (a library warning)."""
    import warnings

    import matplotlib.pyplot as plt

    fig, ax = plt.subplots()
    ax.set_title(name)
    ax.plot([0, 1], [0, 1], label=name)
    ax.legend()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        plots.save(fig, tmp_path / "f.png")
    plt.close(fig)
    assert (tmp_path / "f.png").stat().st_size > 0
