"""``clm-sim export-ff``: the exported C (compiled by gcc, called through ctypes) and the ONNX
graph (run by ONNX Runtime) compute the product's own feedforward.

Oracle: ``model.feedforward(r, ts)``, the product's Python path that the replay applies
(finite differences, zero-phase filter by ``sosfiltfilt``, network, held average), which the
export re-implements differently (an FIR window of the reference). Tolerances are relative to
the largest force of the record.
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from clm_sim.effects import (
    CableSlab,
    Cogging,
    ForceOffset,
    ForceRipple,
    FrictionAsymmetry,
    Presliding,
    Stribeck,
)
from clm_sim.errors import UserError
from clm_sim.loop import simulate
from clm_sim.reference import PointToPoint
from controllers.export import c_source
from controllers.export.cbuild import CompiledFeedforward, compiler
from controllers.export.window import filtfilt_kernel, from_lip, from_pgnn
from controllers.lip import LIPFeedforward
from experiments.cli import main
from experiments.config import ExperimentConfig, Training
from experiments.export_ff import export, load_feedforward
from experiments.testbed import Testbed

TS = 1e-4
# The issue's tolerance. Measured for the n_l = 16 PGNN: about 2e-15 of the peak force for the C
# (both forms) and ONNX Runtime (float64 rounding through a 1139-tap FIR and a network; the
# differences are taken in the product's order); 0 for a LIP.
REL = 1e-12
needs_cc = pytest.mark.skipif(compiler() is None, reason="no C compiler (gcc, cc or clang) on "
                              "this machine: the C export is checked by the ONNX and numpy forms")


def random_reference(seed: int) -> np.ndarray:
    """A reference the product never saw: random points, dwells and limits (m)."""
    rng = np.random.default_rng(seed)
    points = np.concatenate([[0.0], rng.uniform(-0.15, 0.15, 5), [0.0]])
    ref = PointToPoint(points_m=tuple(points), dwell_s=float(rng.uniform(0.1, 0.3)),
                       max_velocity=float(rng.uniform(0.02, 0.08)),
                       max_acceleration=float(rng.uniform(1.0, 6.0)),
                       max_jerk=float(rng.uniform(300.0, 2000.0)))
    return ref.sample(TS).r


@pytest.fixture(scope="session")
def testbed():
    return Testbed(ExperimentConfig(training=Training(repeats=1)))


@pytest.fixture(scope="session")
def fitted(testbed):
    """A LIP and an n_l = 16 PGNN fitted quickly on one pass of r1."""
    run = testbed.training_run()
    lip = testbed.fit_lip(run)
    pgnn = testbed.fit_pgnn(run, hidden=16, lip=lip, max_iter=5)
    return {"lip": lip, "pgnn": pgnn}


@pytest.fixture(scope="session")
def effects_lip(fitted):
    """A LIP with every exportable effect (as a diagnosis extends a model)."""
    return LIPFeedforward.fitted(theta=fitted["lip"].theta_, effects=(
        Cogging(amplitude=1.5, period=0.016, phase=0.3), ForceRipple(amplitude=0.02),
        CableSlab(coefficients=(0.5, 10.0, -30.0, 2000.0), center=0.01),
        Stribeck(peak=2.0, velocity=0.002), FrictionAsymmetry(coulomb_pos=0.4, coulomb_neg=0.7,
                                                              viscous_pos=1.0, viscous_neg=2.0),
        ForceOffset(force_n=-0.8)))


@pytest.fixture(scope="session")
def references(testbed):
    return {"r1": testbed.reference("r1"), "r2": testbed.reference("r2"),
            "random": random_reference(2026)}


def _model(name, fitted, effects_lip):
    if name == "lip_effects":
        return effects_lip, from_lip(effects_lip, TS, "test")
    model = fitted[name]
    return model, (from_lip if name == "lip" else from_pgnn)(model, TS, "test")


def _rel(got, want) -> float:
    return float(np.max(np.abs(got - want)) / np.max(np.abs(want)))


@pytest.fixture(scope="session")
def compiled(fitted, effects_lip, tmp_path_factory):
    """The C of each model compiled at -O2, also with -DCLM_FF_PORTABLE (the portable C where the
    default takes the AVX2 path) and with -DCLM_FF_FLOAT."""
    if compiler() is None:
        pytest.skip("no C compiler")
    out = {}
    for name in ("lip", "pgnn", "lip_effects"):
        _, wf = _model(name, fitted, effects_lip)
        folder = tmp_path_factory.mktemp(name)
        c_source.write(wf, folder)
        out[name] = CompiledFeedforward(folder)
        out[name + "_portable"] = CompiledFeedforward(folder, ("-O2", "-DCLM_FF_PORTABLE"))
        out[name + "_float"] = CompiledFeedforward(folder, ("-O2", "-DCLM_FF_FLOAT"))
    return out


# -- the window form (numpy) -------------------------------------------------------------------
def test_filter_kernel_is_sosfiltfilt_away_from_the_ends():
    x = np.random.default_rng(0).standard_normal(6000)
    h = filtfilt_kernel(4, 250.0, TS)
    import scipy.signal
    sos = scipy.signal.butter(4, 250.0, fs=1 / TS, output="sos")
    want = scipy.signal.sosfiltfilt(sos, x)
    m = (len(h) - 1) // 2
    got = np.convolve(x, h, mode="valid")  # symmetric kernel: convolution = correlation
    mid = slice(2000, 4000)
    assert np.max(np.abs(got[mid.start - m:mid.stop - m] - want[mid])) < 1e-13


@pytest.mark.parametrize("name", ["lip", "pgnn", "lip_effects"])
def test_window_form_is_the_product_feedforward(name, fitted, effects_lip, references):
    model, wf = _model(name, fitted, effects_lip)
    assert (wf.lag, wf.lead) == ((1, 2) if name != "pgnn" else (wf.half + 1, wf.half + 2))
    step = 1 if name != "pgnn" else 11  # every 11th of the 1142-sample PGNN windows (time)
    for r in references.values():
        w = wf.windows(r)[::step]
        got = np.concatenate([wf(w[i:i + 2048]) for i in range(0, len(w), 2048)])
        assert _rel(got, model.feedforward(r, TS)[::step]) < REL


def test_presliding_and_position_lowpass_are_refused(fitted):
    lip = LIPFeedforward.fitted(theta=fitted["lip"].theta_, effects=(Presliding(),))
    with pytest.raises(UserError, match="pre-sliding"):
        from_lip(lip, TS, "test")


# -- C -----------------------------------------------------------------------------------------
@needs_cc
@pytest.mark.parametrize("build", ["", "_portable"])
@pytest.mark.parametrize("name", ["lip", "pgnn", "lip_effects"])
def test_compiled_c_is_the_product_feedforward(name, build, fitted, effects_lip, references,
                                               compiled):
    model, wf = _model(name, fitted, effects_lip)
    c = compiled[name + build]
    assert (c.lag, c.lead) == (wf.lag, wf.lead)
    for key, r in references.items():
        want = model.feedforward(r, TS)
        assert _rel(c.stream(r), want) < REL, key  # every sample, through the ring buffer
        k = np.arange(0, len(r), 997)  # the stateless call on windows
        assert _rel(c(wf.windows(r)[k]), want[k]) < REL, key


def _cpu_has_avx2_fma() -> bool:
    try:
        flags = Path("/proc/cpuinfo").read_text().split()
    except OSError:
        return False
    return "avx2" in flags and "fma" in flags


@needs_cc
@pytest.mark.skipif(not _cpu_has_avx2_fma(), reason="the CPU has no AVX2 and FMA (or this is not "
                    "Linux): only the portable path runs here")
def test_avx2_path_runs_here_and_agrees_with_the_portable_c(fitted, effects_lip, references,
                                                            compiled):
    """On a CPU with AVX2 and FMA the default build takes its vector path: its sums are taken in
    another order, so its forces differ from the portable build's in the last bits, and by no
    more than rounding."""
    _, wf = _model("pgnn", fitted, effects_lip)
    r = references["random"]
    w = wf.windows(r)[::53]
    fast, portable = compiled["pgnn"](w), compiled["pgnn_portable"](w)
    assert np.any(fast != portable)
    assert _rel(fast, portable) < 1e-13
    fast, portable = compiled["pgnn"].stream(r), compiled["pgnn_portable"].stream(r)
    assert np.any(fast != portable)
    assert _rel(fast, portable) < 1e-13


@needs_cc
@pytest.mark.parametrize("name", ["lip", "pgnn", "lip_effects"])
def test_float32_build_error_is_small(name, fitted, effects_lip, references, compiled):
    """-DCLM_FF_FLOAT: single-precision arithmetic after the float64 differences; measured
    ~3e-7 of the peak force, so 1e-5 leaves room for other models."""
    model, wf = _model(name, fitted, effects_lip)
    r = references["random"]
    want = model.feedforward(r, TS)
    assert _rel(compiled[name + "_float"].stream(r), want) < 1e-5
    k = np.arange(0, len(r), 97)
    assert _rel(compiled[name + "_float"](wf.windows(r)[k]), want[k]) < 1e-5


@needs_cc
def test_replay_driven_by_the_c_gives_the_python_mae(testbed, fitted, references, compiled):
    r = references["random"]
    python = testbed.replay(fitted["pgnn"], r)
    c = simulate(testbed.machine, testbed.pid, r, TS, u_ff=compiled["pgnn"].stream(r))
    assert abs(c.mae - python.mae) <= 1e-9 * python.mae


def test_header_states_the_contract(fitted):
    wf = from_pgnn(fitted["pgnn"], TS, "test")
    h, c = c_source.header(wf), c_source.source(wf)
    assert re.search(r"#define CLM_FF_TS 0\.0001\b", h)
    assert f"#define CLM_FF_LAG {wf.lag} " in h and f"#define CLM_FF_LEAD {wf.lead} " in h
    assert "double clm_ff(const double *r);" in h
    assert "malloc" not in c  # no heap
    assert all(line.startswith("static const") for line in c.splitlines()
               if line.startswith("static") and "=" in line)  # no mutable globals


# -- ONNX --------------------------------------------------------------------------------------
def _onnx_session(path):
    onnx = pytest.importorskip("onnx")
    ort = pytest.importorskip("onnxruntime")
    meta = {p.key: p.value for p in onnx.load(str(path)).metadata_props}
    return ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]), meta


def _onnx_apply(session, meta, r, step=1, chunk=4000):
    """u_ff of record r by ONNX Runtime on windows built from the metadata's lag and lead."""
    lag, lead = int(meta["lag"]), int(meta["lead"])
    padded = np.concatenate([np.full(lag, r[0]), r, np.full(lead, r[-1])])
    windows = np.lib.stride_tricks.sliding_window_view(padded, lag + 1 + lead)[::step]
    return np.concatenate([session.run(["u_ff"], {"r_window": np.ascontiguousarray(
        windows[i:i + chunk])})[0] for i in range(0, len(windows), chunk)])


@pytest.mark.parametrize("name", ["lip", "pgnn", "lip_effects"])
def test_onnx_is_the_product_feedforward(name, fitted, effects_lip, references, tmp_path):
    pytest.importorskip("onnx")
    from controllers.export import onnx_graph
    model, wf = _model(name, fitted, effects_lip)
    onnx_graph.write(wf, tmp_path)
    session, meta = _onnx_session(tmp_path / "clm_ff.onnx")
    assert float(meta["ts"]) == TS and "m" in meta["units"] and "N" in meta["units"]
    for key, r in references.items():
        step = 1 if name != "pgnn" else 7  # every 7th window of the 1142-sample PGNN form
        got = _onnx_apply(session, meta, r, step)
        assert got.dtype == np.float64
        assert _rel(got, model.feedforward(r, TS)[::step]) < REL, key


# -- the command ---------------------------------------------------------------------------------
RUN_CONFIG = """\
name: export
seed: 1
references:
  r1: {points_m: [0.0, 0.01, -0.01, 0.0], dwell_s: 0.1}
  r2: {points_m: [0.0, 0.02, 0.0], dwell_s: 0.1}
training: {repeats: 1}
feedforwards:
  - {kind: lip}
  - {kind: pgnn, training: simultaneous, lambda: 0, hidden: 16, pgnn: {max_iter: 5}}
"""


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory):
    """A small clm-sim run with a LIP and an n_l = 16 PGNN (its params/ as the command
    saves them)."""
    tmp = tmp_path_factory.mktemp("run")
    cfg = tmp / "export.yaml"
    cfg.write_text(RUN_CONFIG)
    assert main(["run", str(cfg), "--out", str(tmp / "res"), "--quiet"]) == 0
    return tmp / "res"


OWN_HARNESS = r"""
#include <stdio.h>
#include <stdlib.h>
#include "clm_ff.h"
/* argv[1]: n doubles r[0..n-1] (m); argv[2]: n doubles u_ff (N). The reference is held at its
 * ends: CLM_FF_LAG samples before, CLM_FF_LEAD after. */
int main(int argc, char **argv)
{
    FILE *f = fopen(argv[1], "rb");
    long n, k;
    double *r, *u;
    if (argc != 3 || !f) return 1;
    fseek(f, 0, SEEK_END);
    n = ftell(f) / (long)sizeof(double);
    rewind(f);
    r = malloc(sizeof(double) * (size_t)(n + CLM_FF_WINDOW));
    u = malloc(sizeof(double) * (size_t)n);
    if (fread(r + CLM_FF_LAG, sizeof(double), (size_t)n, f) != (size_t)n) return 1;
    fclose(f);
    for (k = 0; k < CLM_FF_LAG; ++k) r[k] = r[CLM_FF_LAG];
    for (k = 0; k < CLM_FF_LEAD; ++k) r[CLM_FF_LAG + n + k] = r[CLM_FF_LAG + n - 1];
    for (k = 0; k < n; ++k) u[k] = clm_ff(&r[CLM_FF_LAG + k]);
    f = fopen(argv[2], "wb");
    fwrite(u, sizeof(double), (size_t)n, f);
    fclose(f);
    return 0;
}
"""


def _own_harness(folder: Path, r: np.ndarray) -> np.ndarray:
    """u_ff of r through ``clm_ff`` called by a stand-alone program (``OWN_HARNESS``)."""
    import subprocess
    (folder / "main.c").write_text(OWN_HARNESS)
    exe = folder / "own_harness"
    subprocess.run([compiler(), "-O2", "-o", str(exe), str(folder / "main.c"),
                    str(folder / "clm_ff.c"), "-I", str(folder), "-lm"], check=True)
    np.asarray(r, dtype="<f8").tofile(folder / "r.bin")
    subprocess.run([str(exe), str(folder / "r.bin"), str(folder / "u.bin")], check=True)
    return np.fromfile(folder / "u.bin", dtype="<f8")


@pytest.mark.slow
def test_cli_exports_a_run_pgnn_that_matches_on_an_unseen_reference(run_folder, tmp_path,
                                                                     capsys):
    """The issue's bar: a PGNN fitted by ``clm-sim run``, a reference it never saw, the C
    compiled against the header alone and ONNX Runtime with the metadata's lag."""
    from controllers.pgnn import PGNNFeedforward
    pt = next((run_folder / "params").glob("*_seed0.pt"))
    model = PGNNFeedforward.load(pt.with_suffix(""))
    r = random_reference(7)
    want = model.feedforward(r, TS)
    assert main(["export-ff", str(pt), "--to", "onnx", "--out", str(tmp_path / "onnx")]) == 0
    session, meta = _onnx_session(tmp_path / "onnx" / "clm_ff.onnx")
    assert _rel(_onnx_apply(session, meta, r, 5), want[::5]) < 1e-9
    if compiler() is None:
        pytest.skip("no C compiler")
    assert main(["export-ff", str(pt), "--to", "c", "--out", str(tmp_path / "c")]) == 0
    c = CompiledFeedforward(tmp_path / "c")
    assert _rel(c.stream(r), want) < 1e-9
    # a harness of its own, as a user writes it from the header: a program, plain cc -O2
    assert _rel(_own_harness(tmp_path / "c", r), want) < 1e-9
    info = json.loads((tmp_path / "c" / "export.json").read_text())
    assert (info["kind"], info["lag"], info["lead"]) == ("pgnn", c.lag, c.lead)
    capsys.readouterr()


@pytest.mark.slow
def test_cli_exports_the_run_lip(run_folder, tmp_path):
    lip_file = run_folder / "params" / "lip.json"
    wf = load_feedforward(lip_file)
    assert wf.ts == TS and wf.kind == "lip"
    assert main(["export-ff", str(lip_file), "--to", "c", "--out", str(tmp_path / "c")]) == 0
    assert sorted(p.name for p in (tmp_path / "c").iterdir()) == ["clm_ff.c", "clm_ff.h",
                                                                   "export.json"]


def test_identify_and_diagnosis_files_load(fitted, effects_lip, tmp_path):
    lip_file = tmp_path / "lip.json"
    lip_file.write_text(json.dumps({**fitted["lip"].to_json(), "source": "x.csv"}))
    r = random_reference(3)
    assert _rel(load_feedforward(lip_file).apply(r), fitted["lip"].feedforward(r, TS)) < REL
    diag = tmp_path / "diagnosis.json"
    diag.write_text(json.dumps({"record": {"sample_time_s": TS}, "extended_model": {
        **effects_lip.theta_, "effects": [e.as_config() for e in effects_lip.effects_]}}))
    assert _rel(load_feedforward(diag).apply(r), effects_lip.feedforward(r, TS)) < REL
    no_ts = tmp_path / "old.json"
    no_ts.write_text(json.dumps({"kind": "lip", **fitted["lip"].theta_}))
    with pytest.raises(UserError, match="--ts"):
        load_feedforward(no_ts)
    assert load_feedforward(no_ts, ts=TS).ts == TS
    with pytest.raises(UserError, match="contradicts"):
        load_feedforward(lip_file, ts=1e-3)


@pytest.mark.parametrize("case", ["missing", "foreign", "foreign_pt", "unknown_to",
                                  "unwritable", "out_is_a_file", "foreign_folder",
                                  "filter_tail_zero", "filter_tail_large"])
def test_bad_input_is_one_line_exit_2_nothing_written(case, fitted, tmp_path, capsys):
    lip_file = tmp_path / "lip.json"
    lip_file.write_text(json.dumps(fitted["lip"].to_json()))
    model, to, out, extra = lip_file, "c", tmp_path / "out", []
    if case == "missing":
        model = tmp_path / "nope.json"
    elif case == "foreign":
        model = tmp_path / "table.json"
        model.write_text(json.dumps({"rows": []}))
    elif case == "foreign_pt":
        model = tmp_path / "w.pt"
        model.write_bytes(b"not a tensor file")
        model.with_suffix(".json").write_text(json.dumps({"kind": "pgnn"}))
    elif case == "unknown_to":
        to = "rust"
    elif case == "unwritable":
        locked = tmp_path / "locked"
        locked.mkdir()
        locked.chmod(0o500)
        out = locked / "out"
    elif case == "out_is_a_file":
        out = tmp_path / "file"
        out.write_text("x")
    elif case == "foreign_folder":
        out.mkdir()
        (out / "notes.txt").write_text("mine")
    elif case == "filter_tail_zero":
        extra = ["--filter-tail", "0"]
    elif case == "filter_tail_large":
        extra = ["--filter-tail", "0.5"]
    before = sorted(p.name for p in tmp_path.rglob("*"))
    code = main(["export-ff", str(model), "--to", to, "--out", str(out), *extra])
    err = capsys.readouterr().err.strip().splitlines()
    if case == "unwritable":
        (tmp_path / "locked").chmod(0o700)
        if code == 0:  # root writes anywhere
            shutil.rmtree(out)
            pytest.skip("running as root: no folder is unwritable")
    assert code == 2 and len(err) == 1 and err[0].startswith("clm-sim: error: "), err
    assert sorted(p.name for p in tmp_path.rglob("*")) == before


@needs_cc
@pytest.mark.parametrize("activation", ["tanh", "sigmoid", "silu"])
def test_vector_exp_over_the_whole_range(activation, fitted, references, tmp_path):
    """The AVX2 path's own exp over its whole range: a first layer drawn so that its sixteen units
    see pre-activations of typical size 0.01 to 3000 (small arguments, the middle, saturation and
    the +-708 clamp); the C (both builds) equals the numpy window form within 1e-12."""
    import dataclasses
    _, wf = _model("pgnn", fitted, None)
    (w0, b0), *rest = wf.network.layers
    rng = np.random.default_rng(4)
    scale = np.logspace(-2, 3.5, len(b0))[:, None]
    net = dataclasses.replace(wf.network, activation=activation, layers=(
        (scale * rng.standard_normal(w0.shape), scale[:, 0] * rng.standard_normal(len(b0))),
        *rest))
    wf = dataclasses.replace(wf, network=net)
    windows = wf.windows(references["random"])[::211]
    c_source.write(wf, tmp_path)
    with np.errstate(over="ignore"):  # numpy's exp of the saturated units
        want = wf(windows)
    for flags in (("-O2",), ("-O2", "-DCLM_FF_PORTABLE")):
        assert _rel(CompiledFeedforward(tmp_path, flags)(windows), want) < REL, flags


@needs_cc
def test_filter_tail_shortens_the_window_at_a_bounded_cost(fitted, references, tmp_path, capsys):
    """``--filter-tail 1e-9``: the feature filter cut where a 1e-9 share of its weight is left
    out. The window and the look-ahead shrink (569 -> 336 samples a side at 250 Hz), and the
    force moves from the product's by that share amplified through the network: measured 1e-10
    of the peak on r2, bounded here by 1000 times the share."""
    model = fitted["pgnn"]
    model.save(tmp_path / "pgnn")
    out = tmp_path / "ff"
    assert main(["export-ff", str(tmp_path / "pgnn.pt"), "--to", "c", "--out", str(out),
                 "--ts", str(TS), "--filter-tail", "1e-9"]) == 0
    capsys.readouterr()
    info = json.loads((out / "export.json").read_text())
    exact = from_pgnn(model, TS, "test")
    assert info["filter_tail"] == 1e-9 and info["lead"] < exact.lead - 100
    c = CompiledFeedforward(out)
    assert (c.lag, c.lead) == (info["lag"], info["lead"])
    r = references["r2"]
    error = _rel(c.stream(r), model.feedforward(r, TS))
    assert 1e-13 < error < 1e-6, error  # it does cut (not rounding), and within the bound


def test_export_refuses_unknown_target_before_reading(tmp_path):
    with pytest.raises(UserError, match="--to"):
        export(tmp_path / "nope.json", "matlab", tmp_path / "out")


# -- other networks: widths, activations, no feature filter -------------------------------------
VARIANTS = {"sigmoid_2_layers": ("sigmoid", (6, 5), 250.0), "softplus": ("softplus", (8,), 250.0),
            "gelu": ("gelu", (8,), 250.0), "silu_unfiltered": ("silu", (8,), None),
            "relu_400hz": ("relu", (8,), 400.0)}


@pytest.fixture(scope="session")
def training_run(testbed):
    return testbed.training_run()


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_network_variants_export(variant, training_run, fitted, tmp_path):
    """Any widths and activations, and a PGNN without the feature filter: the C (stateless and
    streaming) and, where the activation has an ONNX form, ONNX Runtime equal the product."""
    from clm_sim.features import FeatureMap
    from controllers.pgnn import PGNNFeedforward
    activation, hidden, cutoff = VARIANTS[variant]
    model = PGNNFeedforward(hidden=hidden, activation=activation, max_iter=3,
                            features=FeatureMap(regression_lowpass_hz=cutoff)).fit(
        y=training_run.y, u=training_run.u, ts=TS, theta_lip=fitted["lip"].theta_,
        rng=np.random.default_rng(5))
    wf = from_pgnn(model, TS, variant)
    r = random_reference(11)
    want = model.feedforward(r, TS)
    if compiler() is not None:
        c_source.write(wf, tmp_path)
        k = np.arange(0, len(r), 101)
        for flags in (("-O2",), ("-O2", "-DCLM_FF_PORTABLE")):  # the AVX2 path and the portable
            c = CompiledFeedforward(tmp_path, flags)
            assert _rel(c(wf.windows(r)[k]), want[k]) < REL, flags
            assert _rel(c.stream(r), want) < REL, flags
    pytest.importorskip("onnx")
    from controllers.export import onnx_graph
    if activation in ("softplus", "gelu"):
        with pytest.raises(UserError, match="ONNX"):
            onnx_graph.model(wf)
        return
    onnx_graph.write(wf, tmp_path)
    session, meta = _onnx_session(tmp_path / "clm_ff.onnx")
    assert _rel(_onnx_apply(session, meta, r, 11), want[::11]) < REL


def test_identify_output_exports(training_run, tmp_path, capsys):
    """``clm-sim identify`` on a record, then ``export-ff`` of its lip.json (ts from the file)."""
    from clm_sim.record import save_npz
    save_npz(training_run, tmp_path / "train.npz")
    assert main(["identify", str(tmp_path / "train.npz"), "--out", str(tmp_path / "id")]) == 0
    assert main(["export-ff", str(tmp_path / "id" / "lip.json"), "--to", "c", "--out",
                 str(tmp_path / "c")]) == 0
    capsys.readouterr()
    wf = load_feedforward(tmp_path / "id" / "lip.json")
    data = json.loads((tmp_path / "id" / "lip.json").read_text())
    lip = LIPFeedforward.fitted(theta=data, ts=data["ts"])
    r = random_reference(5)
    # the record's ts, from its time stamps: 1e-4 within rounding; the export keeps its bits
    assert abs(wf.ts - TS) < 1e-12 * TS and wf.ts == data["ts"]
    want = lip.feedforward(r, wf.ts)
    assert _rel(wf.apply(r), want) == 0.0
    if compiler() is not None:
        assert _rel(CompiledFeedforward(tmp_path / "c").stream(r), want) == 0.0
