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
from build_once import build_once

from clm_sim.effects.friction import FrictionAsymmetry, Presliding, Stribeck
from clm_sim.effects.position import CableSlab, Cogging, ForceOffset, ForceRipple
from clm_sim.errors import UserError
from clm_sim.outdir import MANIFEST
from clm_sim.loop import simulate
from clm_sim.reference import PointToPoint
from controllers.export import c_source
from controllers.export.cbuild import CompiledFeedforward, compiler
from controllers.export.options import safe_text
from controllers.export.window import filtfilt_kernel, from_lip, from_pgnn
from controllers.lip import LIPFeedforward
from experiments.cli import main
from experiments.cli.export_ff import export, load_feedforward
from experiments.config import ExperimentConfig, Training
from experiments.testbed import Testbed

TS = 1e-4
# The issue's tolerance. Measured for the n_l = 16 PGNN: about 2e-15 of the peak force for the C
# (both forms) and ONNX Runtime (float64 rounding through a 1139-tap FIR and a network; the
# differences are taken in the product's order); 0 for a LIP.
REL = 1e-12
needs_cc = pytest.mark.skipif(compiler() is None, reason="no C compiler (gcc, cc or clang) on "
                              "this machine: the C export is checked by the ONNX and numpy forms")


@pytest.fixture(autouse=True)
def _one_thread_per_pool():
    """Every test here on one BLAS (and torch) thread. The checks are long products of large
    arrays (the FIR windows of whole records, the oracle's autocorrelation of 16k samples);
    OpenBLAS's second thread spins while it waits for a core, and with two pytest-xdist workers
    on two cores it waits long: the autocorrelation alone took 8 s to 80 s, 0.1 s on one thread.
    No check here is about threads; what they compare is summed per row either way."""
    from clm_sim.numerics import single_threaded
    with single_threaded():
        yield


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
        got = np.concatenate([wf(w[i:i + 256]) for i in range(0, len(w), 256)])
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
    """-DCLM_FF_FLOAT reads the reference as int64 counts of CLM_FF_COUNT_M m and computes in
    float only: against the product on the same counts (the build's own error, not the rounding
    to counts) measured 1e-7 of the peak force for the LIPs, 4e-7 (clm_ff) and 3e-6 (the stream,
    whose recursion runs in float) for the PGNN; 3e-5 leaves room for other models."""
    model, wf = _model(name, fitted, effects_lip)
    c = compiled[name + "_float"]
    assert c.count_m == 1e-12
    r = references["random"]
    rq = c.quantized(r)
    assert 0 < np.max(np.abs(rq - r)) <= 0.51 * c.count_m  # half a count, and the rounding of m
    want = model.feedforward(rq, TS)
    assert _rel(c.stream(r), want) < 3e-5
    k = np.arange(0, len(r), 97)
    assert _rel(c(wf.windows(r)[k]), want[k]) < 3e-5


@needs_cc
@pytest.mark.skipif(not Path("/proc/cpuinfo").is_file() or "x86_64" not in
                    __import__("platform").machine(), reason="reads x86-64 assembly")
@pytest.mark.parametrize("name", ["pgnn", "lip_effects"])
def test_float32_build_computes_no_double(name, fitted, effects_lip, tmp_path):
    """The float build is for an FPU without double precision: compiled at -O2 it holds no
    double-precision instruction (x86-64: no ``*sd`` instruction such as mulsd, cvtss2sd, movsd)
    and -Wdouble-promotion finds no float promoted to double; the maths it calls are the float
    functions (expf, sinf, ...). The default build does use them (the check can fail)."""
    import subprocess
    _, wf = _model(name, fitted, effects_lip)
    c_source.write(wf, tmp_path)
    for build, doubles in ((("-DCLM_FF_FLOAT", "-Wdouble-promotion"), False), ((), True)):
        for f in ("clm_ff.c", "clm_ff_selftest.c"):
            done = subprocess.run([compiler(), *STRICT, *build, "-O2", "-S", "-o", "-",
                                   str(tmp_path / f), "-I", str(tmp_path)],
                                  capture_output=True, text=True)
            assert done.returncode == 0, done.stderr
            found = set(re.findall(r"^\s+(\w+sd)\b", done.stdout, re.M))
            calls = set(re.findall(r"call\s+(\w+)", done.stdout))
            if not doubles:
                assert not found, (f, found)
                assert not calls & {"exp", "sin", "pow", "fabs", "log1p", "erf", "sqrt"}, calls
            elif f == "clm_ff.c":
                assert found


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
    assert "clm_ff_real clm_ff(const clm_ff_pos *r);" in h
    # the default build's types are double (m, N); the float build's int64 counts and float
    assert re.search(r"#else\ntypedef double clm_ff_pos;.*\ntypedef double clm_ff_real;", h)
    assert "typedef int64_t clm_ff_pos;" in h and "typedef float clm_ff_real;" in h
    assert "malloc" not in c  # no heap
    assert all(line.startswith("static const") for line in c.splitlines()
               if line.startswith("static") and "=" in line)  # no mutable globals


# -- ONNX --------------------------------------------------------------------------------------
def _onnx_session(path):
    onnx = pytest.importorskip("onnx")
    ort = pytest.importorskip("onnxruntime")
    meta = {p.key: p.value for p in onnx.load(str(path)).metadata_props}
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1  # as BLAS here (_one_thread_per_pool): no spinning thread
    return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"]), meta


def _onnx_apply(session, meta, r, step=1, chunk=256):
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


def _mlp_apply(session, wf, r):
    """u_ff of record r by the plain-MLP graph: the features of every instant (the numpy window
    form's, record held at its ends), the graph's force there, the held average."""
    padded = np.concatenate([np.full(wf.half + 1, r[0]), r, np.full(wf.half + 2, r[-1])])
    w = np.lib.stride_tricks.sliding_window_view(padded, 2 * wf.half + 3)
    p = np.concatenate([session.run(["force"], {"features": wf.features(w[i:i + 256])})[0][:, 0]
                        for i in range(0, len(w), 256)])
    return 0.5 * (p[:-1] + p[1:])


@pytest.mark.parametrize("name", ["pgnn", "lip"])
def test_onnx_mlp_form_is_a_plain_mlp_and_the_product_feedforward(name, fitted, effects_lip,
                                                                  references, tmp_path):
    """--onnx-form mlp: the features in, the force out, MatMul/Add/Tanh only (a LIP: MatMul),
    opset 17 / IR 8, the full checker; ONNX Runtime on the features, held-averaged, equals the
    product's feedforward (its own Python path) within 1e-12 of the peak on r2 and an unseen
    reference; its known-answer vectors are the graph's."""
    onnx = pytest.importorskip("onnx")
    from controllers.export import onnx_graph
    from controllers.export.options import ExportOptions
    model, wf = _model(name, fitted, effects_lip)
    paths = onnx_graph.mlp_write(wf, tmp_path, ExportOptions(prefix="ax"))
    assert [p.name for p in paths] == ["ax.onnx", "ax_kat.csv"]
    proto = onnx.load(str(paths[0]))
    onnx.checker.check_model(proto, full_check=True)
    assert {n.op_type for n in proto.graph.node} <= {"MatMul", "Add", "Tanh"}
    assert (name == "pgnn") == ("Tanh" in {n.op_type for n in proto.graph.node})
    assert (proto.opset_import[0].version, proto.ir_version) == (17, 8)
    assert [i.name for i in proto.graph.input] == ["features"]
    session, meta = _onnx_session(paths[0])
    assert meta["form"] == "mlp" and "N" in meta["units"]
    for key in ("r2", "random"):
        r = references[key]
        assert _rel(_mlp_apply(session, wf, r), model.feedforward(r, TS)) < REL, key
    kat = np.loadtxt(paths[1], delimiter=",", skiprows=2)
    got = session.run(["force"], {"features": kat[:, 1:5]})[0][:, 0]
    assert _rel(got, kat[:, 5]) < REL


def test_onnx_mlp_form_refuses_what_is_not_a_plain_mlp(fitted):
    pytest.importorskip("onnx")
    from controllers.export import onnx_graph
    _, wf = _model("pgnn", fitted, None)
    from dataclasses import replace
    sig = replace(wf, network=replace(wf.network, activation="sigmoid"))
    with pytest.raises(UserError, match="sigmoid"):
        onnx_graph.mlp_model(sig)


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


@pytest.fixture(scope="session")
def run_folder(tmp_path_factory):
    """A small clm-sim run with a LIP and an n_l = 16 PGNN (its params/ as the command
    saves them)."""
    return Path(build_once(tmp_path_factory, "run_folder", _run_for_export))


def _run_for_export(tmp: Path) -> str:
    """The run of :func:`run_folder`, once (over xdist's workers too: its tests only read it)."""
    cfg = tmp / "export.yaml"
    cfg.write_text(RUN_CONFIG)
    assert main(["run", str(cfg), "--out", str(tmp / "res"), "--quiet"]) == 0
    return str(tmp / "res")


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
    assert main(["export-ff", str(pt), "--to", "onnx", "--onnx-form", "mlp", "--out",
                 str(tmp_path / "mlp")]) == 0
    from controllers.export.window import from_pgnn
    session, meta = _onnx_session(tmp_path / "mlp" / "clm_ff.onnx")
    assert _rel(_mlp_apply(session, from_pgnn(model, TS, "x"), r), want) < 1e-9
    assert json.loads((tmp_path / "mlp" / "export.json").read_text())["onnx_form"] == "mlp"
    if compiler() is None:
        pytest.skip("no C compiler")
    # the reference reaches 0.15 m, the run's training data 0.01 m: beyond the default limits
    assert main(["export-ff", str(pt), "--to", "c", "--out", str(tmp_path / "c"),
                 "--no-limits"]) == 0
    c = CompiledFeedforward(tmp_path / "c")
    assert _rel(c.stream(r), want) < 1e-9
    # a harness of its own, as a user writes it from the header: a program, plain cc -O2
    assert _rel(_own_harness(tmp_path / "c", r), want) < 1e-9
    info = json.loads((tmp_path / "c" / "export.json").read_text())
    assert (info["kind"], info["lag"], info["lead"]) == ("pgnn", c.lag, c.lead)
    assert info["float_build"]["count_m"] == 1e-12
    capsys.readouterr()


@pytest.mark.slow
def test_cli_exports_the_run_lip(run_folder, tmp_path):
    lip_file = run_folder / "params" / "lip.json"
    wf = load_feedforward(lip_file)
    assert wf.ts == TS and wf.kind == "lip"
    assert main(["export-ff", str(lip_file), "--to", "c", "--out", str(tmp_path / "c")]) == 0
    assert sorted(p.name for p in (tmp_path / "c").iterdir() if p.name != MANIFEST) == [
        "clm_ff.c", "clm_ff.h", "clm_ff_kat.csv", "clm_ff_selftest.c", "export.json"]
    info = json.loads((tmp_path / "c" / "export.json").read_text())
    assert info["limits_from"].startswith("training.npz")  # the run's data, found beside it
    assert info["r_min"] < -0.01 and info["r_max"] > 0.01 and info["max_force"] > 0


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
                                  "filter_tail_zero", "filter_tail_large", "bad_prefix",
                                  "max_force_nan", "max_slew_negative", "limits_onnx",
                                  "onnx_form_unknown", "onnx_form_c", "count_m_onnx",
                                  "count_m_zero", "mlp_with_effects"])
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
    elif case == "bad_prefix":
        extra = ["--prefix", "Axis-1"]
    elif case == "max_force_nan":
        extra = ["--max-force", "nan"]
    elif case == "max_slew_negative":
        extra = ["--max-slew", "-5"]
    elif case == "limits_onnx":
        to, extra = "onnx", ["--max-force", "10"]
    elif case == "onnx_form_unknown":
        to, extra = "onnx", ["--onnx-form", "tree"]
    elif case == "onnx_form_c":
        extra = ["--onnx-form", "mlp"]
    elif case == "count_m_onnx":
        to, extra = "onnx", ["--count-m", "1e-9"]
    elif case == "count_m_zero":
        extra = ["--count-m", "0"]
    elif case == "mlp_with_effects":
        pytest.importorskip("onnx")
        model = tmp_path / "diagnosis.json"
        model.write_text(json.dumps({"record": {"sample_time_s": TS}, "extended_model": {
            **fitted["lip"].theta_, "effects": [{"type": "force_offset", "force_n": 1.0}]}}))
        to, extra = "onnx", ["--onnx-form", "mlp"]
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
                 "--ts", str(TS), "--filter-tail", "1e-9", "--no-limits"]) == 0
    capsys.readouterr()
    info = json.loads((out / "export.json").read_text())
    exact = from_pgnn(model, TS, "test")
    assert info["filter_tail"] == 1e-9 and info["lead"] < exact.lead - 100
    # the header's claim follows the option: the stream equals clm_ff to about the share
    assert "to about the --filter-tail share" in (out / "clm_ff.h").read_text()
    assert "equals clm_ff to rounding" in c_source.header(exact)
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
    if activation == "gelu":  # erf has no exact ONNX form here
        with pytest.raises(UserError, match="ONNX"):
            onnx_graph.model(wf)
        return
    onnx_graph.write(wf, tmp_path)
    session, meta = _onnx_session(tmp_path / "clm_ff.onnx")
    assert _rel(_onnx_apply(session, meta, r, 11), want[::11]) < REL


def test_identify_output_exports(training_run, tmp_path, capsys):
    """``clm-sim identify`` on a record, then ``export-ff`` of its lip.json (ts from the file)."""
    from clm_sim.records.write import save_npz
    save_npz(training_run, tmp_path / "train.npz")
    assert main(["identify", str(tmp_path / "train.npz"), "--out", str(tmp_path / "id")]) == 0
    assert main(["export-ff", str(tmp_path / "id" / "lip.json"), "--to", "c", "--out",
                 str(tmp_path / "c")]) == 0
    capsys.readouterr()
    wf = load_feedforward(tmp_path / "id" / "lip.json")
    data = json.loads((tmp_path / "id" / "lip.json").read_text())
    lip = LIPFeedforward.fitted(theta=data, ts=data["ts"])
    r = random_reference(5)
    # the record's ts, from its time stamps: 1e-4 within rounding; the export keeps it to 12
    # significant digits (CLM_FF_TS 0.0001, not 9.999999999999999e-05)
    assert abs(wf.ts - TS) < 1e-12 * TS and wf.ts == float(f"{data['ts']:.12g}") == TS
    want = lip.feedforward(r, wf.ts)
    assert _rel(wf.apply(r), want) == 0.0
    if compiler() is not None:
        assert _rel(CompiledFeedforward(tmp_path / "c").stream(r), want) == 0.0


# -- fail-safe: bad samples, limits, restarts --------------------------------------------------
OK, REJECTED, DEGRADED, CLAMPED, SLEWED, STOPPED = 0, 1, 2, 4, 8, 16


def _padded(wf, r):
    return np.concatenate([np.full(wf.lag, r[0]), r, np.full(wf.lead, r[-1])])


@needs_cc
@pytest.mark.parametrize("bad", [np.nan, np.inf, -1e300])
@pytest.mark.parametrize("build", ["", "_portable"])
@pytest.mark.parametrize("name", ["lip", "pgnn"])
def test_a_bad_sample_pushed_gives_a_status_and_the_exact_force_after_the_window(
        name, build, bad, fitted, effects_lip, references, compiled):
    """The issue's bar: one NaN (inf, an absurd position) pushed into the stream, in motion and
    at rest. The push reports REJECTED, the force stays finite (the last good sample held in its
    place), DEGRADED for exactly the window's length, and then the force is the clean stream's:
    bit for bit at rest (the held sample is the rest position), within the export's tolerance
    in motion (the filter's recursion forgets the held sample as its impulse response decays:
    measured ~1e-16 of the peak force; held to REL)."""
    model, wf = _model(name, fitted, effects_lip)
    c = compiled[name + build]
    r = references["random"]
    rp = _padded(wf, r)
    clean, st_clean, init = c.stream_status(rp)
    assert init == OK and not st_clean.any()
    assert _rel(clean, model.feedforward(r, TS)) < REL
    v = np.gradient(r)
    for where in (int(np.argmax(np.abs(v))), len(r) - 2 * wf.width):  # fastest motion; at rest
        bad_rp = rp.copy()
        j = where + wf.lead  # pushed at step j, whose output is sample j - lead
        bad_rp[wf.lag + j] = bad
        u, st, _ = c.stream_status(bad_rp)
        k0 = j - wf.lead
        assert np.all(np.isfinite(u))
        assert st[k0] == REJECTED | DEGRADED
        assert np.all(st[k0 + 1:k0 + wf.width] == DEGRADED) and not st[:k0].any()
        assert not st[k0 + wf.width:].any()
        assert np.array_equal(u[:k0], clean[:k0])
        after = slice(k0 + wf.width, None)
        if where == len(r) - 2 * wf.width:  # at rest: exact
            assert np.array_equal(u[after], clean[after])
        else:
            assert _rel(u[after], clean[after]) < REL


@needs_cc
@pytest.mark.parametrize("name", ["lip", "pgnn", "lip_effects"])
def test_stateless_call_flags_a_bad_window_in_both_builds(name, fitted, effects_lip, references,
                                                          compiled):
    """A NaN or an infinity anywhere in the window: clm_ff gives NaN in both builds (the AVX2
    path does not turn it into a finite force), clm_ff_eval REJECTED and 0 N."""
    _, wf = _model(name, fitted, effects_lip)
    w = wf.windows(references["r2"])[1000:1001].repeat(3 * wf.width, axis=0).copy()
    for i in range(wf.width):
        w[i, i] = np.nan
        w[wf.width + i, i] = np.inf
        w[2 * wf.width + i, i] = -np.inf
    for build in ("", "_portable"):
        c = compiled[name + build]
        assert np.all(np.isnan(c(w))), build
        u, st = c.eval(w)
        assert np.all(st == REJECTED) and np.all(u == 0.0), build


@needs_cc
@pytest.mark.parametrize("name", ["lip", "pgnn"])
def test_start_from_a_window_on_a_moving_reference(name, fitted, effects_lip, references,
                                                   compiled):
    """clm_ff_stream_start at the fastest point of a motion: the force from there on is the
    product's (no 4.7e6 N restart transient): exactly for a LIP, within REL for a PGNN (the
    filter's recursion started from the window)."""
    model, wf = _model(name, fitted, effects_lip)
    r = references["random"]
    k0 = int(np.argmax(np.abs(np.gradient(r))))
    u, st, init = compiled[name].stream_status(_padded(wf, r), start=k0)
    want = model.feedforward(r, TS)
    assert init == OK and not st[k0:].any()
    assert _rel(u[k0:], want[k0:]) < REL
    if name == "lip":
        assert np.array_equal(u[k0:], want[k0:])
    bad = _padded(wf, r)
    bad[wf.lag + k0 - wf.lag] = np.nan  # the oldest sample of the window at k0
    u, st, init = compiled[name].stream_status(bad, start=k0)
    assert init == REJECTED | STOPPED  # and it says so on every push, 0 N
    assert np.all(st[k0:] == REJECTED | STOPPED) and np.all(u[k0 + 1:] == 0.0)


@needs_cc
@pytest.mark.parametrize("name", ["lip", "pgnn"])
def test_force_and_slew_limits_hold_and_report(name, fitted, effects_lip, references, compiled):
    """Limits set at run time: the force never leaves +-max_force, never changes by more than
    max_slew * ts per sample, the status says when and only when a limit acted, and where none
    acted the force is the unlimited one."""
    _, wf = _model(name, fitted, effects_lip)
    c = compiled[name]
    r = references["r2"]
    free, _, _ = c.stream_status(_padded(wf, r))
    peak = np.max(np.abs(free))
    max_force, max_slew = 0.5 * peak, 0.2 * np.max(np.abs(np.diff(free))) / TS
    u, st, init = c.stream_status(_padded(wf, r), max_force=max_force, max_slew=max_slew)
    assert init == OK
    assert np.max(np.abs(u)) <= max_force
    assert np.max(np.abs(np.diff(u))) <= max_slew * TS * (1 + 1e-12)
    assert (st & CLAMPED).any() and (st & SLEWED).any()
    quiet = st == OK
    assert quiet.sum() > len(r) // 2
    # where no limit acted the output follows the unlimited force (once the two have met again)
    first = int(np.argmax(st != OK))
    met = quiet & (np.arange(len(r)) < first)
    assert np.array_equal(u[met], free[met])
    # a limit of 0 or NaN is refused
    for limits in ((float("nan"), 1.0), (0.0, 1.0), (1.0, -1.0)):
        again, _, bad = c.stream_status(_padded(wf, r), max_force=limits[0], max_slew=limits[1])
        assert bad == REJECTED and np.array_equal(again, free), limits


@needs_cc
def test_export_time_limits_and_the_eval_clamp(fitted, references, tmp_path):
    """--max-force at export: the header's default, applied by clm_ff_eval (CLAMPED) and by a
    fresh stream."""
    lip = fitted["lip"]
    lip.save(tmp_path / "lip.json")
    out = tmp_path / "ff"
    assert main(["export-ff", str(tmp_path / "lip.json"), "--to", "c", "--out", str(out),
                 "--ts", str(TS), "--max-force", "5", "--max-slew", "1e5", "--position-range",
                 "-1", "1", "--max-velocity", "10", "--max-acceleration", "1e3"]) == 0
    assert "#define CLM_FF_MAX_FORCE 5.0 " in (out / "clm_ff.h").read_text()
    c = CompiledFeedforward(out)
    wf = load_feedforward(tmp_path / "lip.json", TS)
    r = references["r2"]
    u, st = c.eval(wf.windows(r))
    free = c(wf.windows(r))
    assert np.max(np.abs(free)) > 5 and np.max(np.abs(u)) == 5.0
    assert np.array_equal(st == CLAMPED, np.abs(free) > 5)
    s, sst, _ = c.stream_status(_padded(wf, r))
    assert np.max(np.abs(s)) <= 5.0 and (sst & CLAMPED).any()
    assert np.max(np.abs(np.diff(s))) <= 1e5 * TS * (1 + 1e-12)


# -- names: --prefix, escaping -----------------------------------------------------------------
TWO_MODELS = r"""
#include <stdio.h>
#include "ax.h"
#include "ay.h"
/* Two exports in one program: the same window to both; prints the two forces. */
int main(void)
{
    static double r[AX_WINDOW + AY_WINDOW];
    ax_stream sx;
    ay_stream sy;
    double ux = 0.0, uy = 0.0;
    int i;
    for (i = 0; i < AX_WINDOW + AY_WINDOW; ++i)
        r[i] = (double)(i * i) / 1048576.0; /* exact in binary: the same r as numpy */
    (void)ax_stream_init(&sx, r[0]);
    (void)ay_stream_init(&sy, r[0]);
    for (i = 0; i < AX_WINDOW + AY_WINDOW; ++i) {
        (void)ax_stream_step(&sx, r[i], &ux);
        (void)ay_stream_step(&sy, r[i], &uy);
    }
    printf("%.17g %.17g %.17g %.17g\n", ax(&r[AY_LAG]), ay(&r[AY_LAG]), ux, uy);
    return 0;
}
"""


@needs_cc
def test_two_prefixed_exports_link_and_run_in_one_program(fitted, tmp_path):
    """--prefix ax (a LIP) and --prefix ay (a PGNN): linked side by side and compiled as one
    translation unit (a unity build: the file-local macros and tables must not clash either),
    both with strict warnings; each gives its own model's force."""
    import subprocess
    fitted["lip"].save(tmp_path / "lip.json")
    fitted["pgnn"].save(tmp_path / "pgnn")
    for prefix, model in (("ax", "lip.json"), ("ay", "pgnn.pt")):
        assert main(["export-ff", str(tmp_path / model), "--to", "c", "--out",
                     str(tmp_path / prefix), "--ts", str(TS), "--prefix", prefix,
                     "--no-limits"]) == 0
        assert sorted(p.name for p in (tmp_path / prefix).iterdir()
                      if p.name != MANIFEST) == [
            f"{prefix}.c", f"{prefix}.h", f"{prefix}_kat.csv", f"{prefix}_selftest.c",
            "export.json"]
        text = (tmp_path / prefix / f"{prefix}.c").read_text()
        assert "clm_ff" not in text and "CLM_FF" not in text
    (tmp_path / "main.c").write_text(TWO_MODELS)
    (tmp_path / "unity.c").write_text('#include "ax.c"\n#include "ay.c"\n#include "main.c"\n')
    strict = ["-std=c99", "-Wall", "-Wextra", "-pedantic", "-Wconversion", "-Wshadow", "-Werror",
              "-O2", "-I", str(tmp_path / "ax"), "-I", str(tmp_path / "ay")]
    results = []
    for sources in ([tmp_path / "main.c", tmp_path / "ax" / "ax.c", tmp_path / "ay" / "ay.c"],
                    [tmp_path / "unity.c"]):
        exe = tmp_path / "two"
        subprocess.run([compiler(), *strict, "-I", str(tmp_path), "-o", str(exe),
                        *map(str, sources), "-lm"], check=True)
        results.append(subprocess.run([str(exe)], capture_output=True, text=True,
                                      check=True).stdout.split())
    assert results[0] == results[1]
    ux, uy = (float(x) for x in results[0][:2])
    wl = load_feedforward(tmp_path / "lip.json", TS)
    wp = load_feedforward(tmp_path / "pgnn.pt", TS)
    n = wl.width + wp.width
    r = np.arange(n, dtype=float) ** 2 / 1048576.0
    k = wp.lag  # r[AY_LAG] is the sample both were called for
    assert ux == pytest.approx(float(wl(r[None, k - wl.lag:k + wl.lead + 1])[0]), rel=1e-12)
    assert uy == pytest.approx(float(wp(r[None, k - wp.lag:k + wp.lead + 1])[0]), rel=1e-12)


@pytest.mark.parametrize("prefix", ["", "Ax", "1ax", "a-b", "int", "a" * 40, "ax\\\nint x;"])
def test_a_bad_prefix_is_refused(prefix, tmp_path):
    with pytest.raises(UserError, match="--prefix"):
        export(tmp_path / "nope.json", "c", tmp_path / "out", prefix=prefix)


@needs_cc
def test_a_model_file_name_cannot_inject_code(fitted, tmp_path):
    """A file name with a backslash-newline (line splicing), a comment end,
    a trigraph and a quote. The name reaches the header and export.json only as safe text,
    and a program that includes the header does not see the injected declaration."""
    import subprocess
    name = 'x\\\nint injected = 1; ??=\n"q"*.json'  # a file name cannot hold a '/'

    folder = tmp_path / "m"
    folder.mkdir()
    fitted["lip"].save(folder / name)
    out = tmp_path / "ff"
    assert main(["export-ff", str(folder / name), "--to", "c", "--out", str(out),
                 "--ts", str(TS), "--no-limits"]) == 0
    h = (out / "clm_ff.h").read_text()
    assert "\\" not in h and "??" not in h and '"q"' not in h
    assert h.count("*/") == h.count("/*")  # every comment closes where it was opened
    info = json.loads((out / "export.json").read_text())
    assert info["model"] == info["trace"]["model_file"] == safe_text(name)
    assert set(safe_text(name)) <= set("xint jecd=1;_q.son")
    (tmp_path / "probe.c").write_text('#include "clm_ff.h"\nint main(void) { return injected; }\n')
    done = subprocess.run([compiler(), "-std=c99", "-I", str(out), "-c", "-o",
                           str(tmp_path / "probe.o"), str(tmp_path / "probe.c")],
                          capture_output=True, text=True)
    assert done.returncode != 0 and "injected" in done.stderr


def test_safe_text_defuses_what_c_and_json_would_read():
    text = safe_text('a\\\nb */ ??/ "c" \'d\' \x00 \u00e9 `e` $f {g}')
    assert all(bad not in text for bad in ("\\", "\n", "*/", "??", '"', "'", "\x00", "`", "$"))
    assert text.startswith("a__b") and "_c_" in text


# -- strict warnings in every shape and build ------------------------------------------------------
def _shape(hidden, activation, cutoff=2000.0):
    """A PGNN window form with random weights (compile-only: the numbers do not matter)."""
    from controllers.export.window import Network
    rng = np.random.default_rng(len(hidden))
    layers, width = [], 4
    for h in hidden:
        layers.append((rng.standard_normal((h, width)), rng.standard_normal(h)))
        width = h
    net = Network(np.zeros(4), np.ones(4), tuple(layers), activation,
                  rng.standard_normal(width), 0.1)
    kernel = filtfilt_kernel(4, cutoff, TS, 1e-15) if cutoff else np.ones(1)
    from controllers.export.window import WindowFeedforward
    return WindowFeedforward(ts=TS, theta={"mass": 1.0, "viscous": 2.0, "coulomb": 0.5,
                                           "stiffness": 3.0}, source="shape", kind="pgnn",
                             kernel=kernel, network=net,
                             filter={"order": 4, "cutoff_hz": cutoff or 0.0, "tol": 1e-15})


STRICT = ("-std=c99", "-Wall", "-Wextra", "-pedantic", "-Wconversion", "-Wshadow", "-Werror")
BUILDS = ((), ("-DCLM_FF_PORTABLE",), ("-DCLM_FF_FLOAT",))


def _compilers():
    import shutil as sh
    return [c for c in dict.fromkeys([compiler(), sh.which("clang") and "clang"]) if c]


@needs_cc
@pytest.mark.parametrize("cc", _compilers())
def test_strict_warnings_matrix(cc, effects_lip, tmp_path):
    """Every network shape (1 to 3 hidden layers, each activation, with and without the feature
    filter), the LIP with every effect and without: the generated C compiles with no warning under
    -std=c99 -Wall -Wextra -pedantic -Wconversion -Wshadow -Werror in every build (default,
    -DCLM_FF_PORTABLE, -DCLM_FF_FLOAT). Syntax and semantic checks only (-fsyntax-only), plus
    one -O2 object per build (warnings that need the optimizer)."""
    import subprocess
    from controllers.activations import ACTIVATIONS
    shapes = {f"{a}_{len(h)}": _shape(h, a) for a in ACTIVATIONS
              for h in ((5,), (5, 3), (3, 5, 4))}
    shapes["raw"] = _shape((4, 4), "tanh", cutoff=None)
    shapes["lip_effects"] = from_lip(effects_lip, TS, "effects")
    shapes["lip"] = from_lip(LIPFeedforward.fitted(theta=effects_lip.theta_), TS, "lip")
    failures = []
    for key, wf in shapes.items():
        folder = tmp_path / key
        folder.mkdir()
        c_source.write(wf, folder)
        for build in BUILDS:
            opt = ["-O2", "-c", "-o", str(folder / "x.o")] if key in ("tanh_2", "lip_effects") \
                else ["-fsyntax-only"]
            done = subprocess.run([cc, *STRICT, *build, *opt, str(folder / "clm_ff.c"), "-I",
                                   str(folder)], capture_output=True, text=True)
            if done.returncode:
                failures.append(f"{key} {build}: {done.stderr[:400]}")
    for key in ("tanh_2", "lip_effects"):  # gcc 12 -ffast-math once warned of a misread loop
        folder = tmp_path / key
        done = subprocess.run([cc, *STRICT, "-O2", "-ffast-math", "-c", "-o", str(folder / "x.o"),
                               str(folder / "clm_ff.c"), "-I", str(folder)],
                              capture_output=True, text=True)
        if done.returncode:
            failures.append(f"{key} -ffast-math: {done.stderr[:400]}")
    assert not failures, "\n".join(failures)


# -- ONNX: opset, IR, initializers, trace ----------------------------------------------------------
@pytest.mark.parametrize("name", ["pgnn", "lip_effects"])
def test_onnx_is_opset_17_consistent_and_lean(name, fitted, effects_lip, tmp_path):
    onnx = pytest.importorskip("onnx")
    from controllers.export import onnx_graph
    from controllers.export.options import ExportOptions
    _, wf = _model(name, fitted, effects_lip)
    proto = onnx_graph.model(wf, ExportOptions(version="9.9.9", model_sha256="ab" * 32))
    assert [o.version for o in proto.opset_import] == [17] and proto.ir_version == 8
    assert max(r[1] for r in onnx.helper.VERSION_TABLE if r[2] == 17) == proto.ir_version
    onnx.checker.check_model(proto, full_check=True)
    used = {i for node in proto.graph.node for i in node.input}
    assert all(t.name in used for t in proto.graph.initializer)
    assert proto.producer_version == "9.9.9"
    meta = {p.key: p.value for p in proto.metadata_props}
    assert meta["model_sha256"] == "ab" * 32 and meta["version"] == "9.9.9"


# -- traceability --------------------------------------------------------------------------------
def test_export_is_traced_and_reproducible(fitted, tmp_path, monkeypatch):
    """Version, commit, date and the model's hash in the header, export.json and the ONNX
    metadata; no machine path anywhere; with SOURCE_DATE_EPOCH two exports are byte-identical."""
    import hashlib
    fitted["lip"].save(tmp_path / "lip.json")
    digest = hashlib.sha256((tmp_path / "lip.json").read_bytes()).hexdigest()
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1790000000")
    outs = []
    for i in range(2):
        out = tmp_path / f"ff{i}"
        export(tmp_path / "lip.json", "c", out, ts=TS, no_limits=True)
        outs.append(out)
    for name in ("clm_ff.h", "clm_ff.c", "export.json"):
        assert (outs[0] / name).read_bytes() == (outs[1] / name).read_bytes(), name
        assert str(tmp_path) not in (outs[0] / name).read_text()
    h = (outs[0] / "clm_ff.h").read_text()
    info = json.loads((outs[0] / "export.json").read_text())
    assert digest in h and info["trace"]["model_sha256"] == digest
    assert info["trace"]["date"] == "2026-09-21T14:13:20Z" and "2026-09-21T14:13:20Z" in h
    assert info["trace"]["version"] and info["trace"]["commit"]
    if pytest.importorskip("onnx"):
        import onnx
        export(tmp_path / "lip.json", "onnx", tmp_path / "onnx", ts=TS)
        proto = onnx.load(str(tmp_path / "onnx" / "clm_ff.onnx"))
        meta = {p.key: p.value for p in proto.metadata_props}
        assert meta["model_sha256"] == digest and str(tmp_path) not in str(meta)


SELFTEST_MAIN = r"""
#include <stdio.h>
#include "clm_ff.h"
int main(void)
{
    static clm_ff_stream scratch;
    const int failed = clm_ff_selftest(&scratch);
    printf("%d\n", failed);
    return failed != 0;
}
"""


@needs_cc
@pytest.mark.parametrize("name", ["lip_effects", "pgnn"])
def test_selftest_passes_in_every_build_and_catches_a_wrong_maths_library(
        name, fitted, effects_lip, tmp_path):
    """clm_ff_selftest() compiled with the export: 0 in the default, portable and float builds;
    a build whose exp (or sin) is not the real one fails it; the vectors file holds the same
    forces as the product's feedforward on its motion."""
    import subprocess
    from controllers.export import selftest
    model, wf = _model(name, fitted, effects_lip)
    c_source.write(wf, tmp_path)
    r, u = selftest.vectors(wf)
    assert _rel(u, model.feedforward(r, TS)) < REL
    kat = np.loadtxt(tmp_path / "clm_ff_kat.csv", delimiter=",", skiprows=2)
    assert np.array_equal(kat[:, 1], r) and np.array_equal(kat[:, 2], u)
    (tmp_path / "main.c").write_text(SELFTEST_MAIN)
    wrong = "-DCLM_FF_SIN=cos" if name == "lip_effects" else "-DCLM_FF_EXP=exp2"
    for flags, passes in (((), True), (("-DCLM_FF_PORTABLE",), True), (("-DCLM_FF_FLOAT",), True),
                          (("-DCLM_FF_PORTABLE", wrong), False)):
        exe = tmp_path / "selftest"
        subprocess.run([compiler(), *STRICT, "-O2", *flags, "-I", str(tmp_path), "-o", str(exe),
                        str(tmp_path / "main.c"), str(tmp_path / "clm_ff.c"),
                        str(tmp_path / "clm_ff_selftest.c"), "-lm"], check=True)
        done = subprocess.run([str(exe)], capture_output=True, text=True)
        assert (done.returncode == 0) == passes, (flags, done.stdout)


SUBNORMALS = r"""
#include <stdio.h>
#include <math.h>
#include "clm_ff.h"
/* A 2 mm move in 0.1 s, then 3 s at rest: how many values of the stream's filter state are
 * subnormal. */
int main(void)
{
    static clm_ff_stream s;
    double sink = 0.0;
    long k, n = 0, c, i;
    (void)clm_ff_stream_init(&s, 0.0);
    for (k = 0; k < 1000; ++k) {
        const double x = (double)k / 1000.0;
        sink += clm_ff_stream_push(&s, 2e-3 * x * x * x * (10.0 - 15.0 * x + 6.0 * x * x));
    }
    for (k = 0; k < 30000; ++k)
        sink += clm_ff_stream_push(&s, 2e-3);
    for (c = 0; c < 4; ++c) {
        for (i = 0; i < 2 * CLM_FF_NSEC; ++i)
            n += fpclassify((&s.zf[c][0][0])[i]) == FP_SUBNORMAL;
        for (i = 0; i < 2 * (CLM_FF_HALF + 1); ++i)
            n += fpclassify(s.fwd[c][i]) == FP_SUBNORMAL;
    }
    printf("%ld %g\n", n, sink);
    return 0;
}
"""


@needs_cc
def test_no_subnormal_state_at_rest_after_a_move(fitted, tmp_path):
    """The issue measured 3,434 subnormal state values 2 s after a move (each push then ~20 %
    slower); the sections' states below 1e-200 are flushed to 0, so none remain."""
    import subprocess
    _, wf = _model("pgnn", fitted, None)
    c_source.write(wf, tmp_path)
    (tmp_path / "main.c").write_text(SUBNORMALS)
    exe = tmp_path / "sub"
    subprocess.run([compiler(), *STRICT, "-O2", "-I", str(tmp_path), "-o", str(exe),
                    str(tmp_path / "main.c"), str(tmp_path / "clm_ff.c"), "-lm"], check=True)
    count, total = subprocess.run([str(exe)], capture_output=True, text=True,
                                  check=True).stdout.split()
    assert int(count) == 0 and np.isfinite(float(total))


RECIPES = r"""
#include <stdio.h>
#include <stdlib.h>
#include "clm_ff.h"
/* The integration recipes of docs/export_targets.md with their delay semantics, over a record r[0..n-1]
 * (argv[1], doubles; held at its ends) whose generator runs CLM_FF_LEAD samples ahead:
 * g(k) = r[k + LEAD]. Writes argv[2]: per sample k, four doubles:
 *   Simulink Tapped Delay, CLM_FF_WINDOW - 1 delays, current input included, oldest first,
 *     initial condition the rest position -> clm_ff_eval on that vector;
 *   the same block without the current input (CLM_FF_WINDOW delays: z^-1 .. z^-N);
 *   a PLC task: cycle k reads g(k), steps the stream, and the feedback's reference is g
 *     delayed by CLM_FF_LEAD cycles -> the force, and that reference. */
static double *r;
static long n;
static double g(long k)
{
    k += CLM_FF_LEAD;
    return r[k < 0 ? 0 : (k >= n ? n - 1 : k)];
}
int main(int argc, char **argv)
{
    FILE *f;
    static double line[CLM_FF_WINDOW + 1], fb_line[CLM_FF_LEAD + 1];
    static clm_ff_stream s;
    double *out, vec[CLM_FF_WINDOW + 1];
    long k, j;
    if (argc != 3 || !(f = fopen(argv[1], "rb"))) return 1;
    fseek(f, 0, SEEK_END);
    n = ftell(f) / (long)sizeof(double);
    rewind(f);
    r = malloc(sizeof(double) * (size_t)n);
    out = malloc(4 * sizeof(double) * (size_t)n);
    if (fread(r, sizeof(double), (size_t)n, f) != (size_t)n) return 1;
    fclose(f);
    for (j = 0; j <= CLM_FF_WINDOW; ++j) line[j] = r[0];    /* initial condition: rest */
    for (j = 0; j <= CLM_FF_LEAD; ++j) fb_line[j] = r[0];
    (void)clm_ff_stream_init(&s, r[0]);
    for (k = 0; k < n; ++k) {
        const double in = g(k);
        /* the delay line holds g(k-1) (line[W-1]) .. g(k-W) (line[0]): oldest first */
        for (j = 0; j < CLM_FF_WINDOW - 1; ++j) vec[j] = line[j + 1];
        vec[CLM_FF_WINDOW - 1] = in;                         /* with the current input */
        (void)clm_ff_eval(vec + CLM_FF_LAG, &out[4 * k]);
        (void)clm_ff_eval(line + CLM_FF_LAG, &out[4 * k + 1]); /* z^-W .. z^-1 only */
        for (j = 0; j < CLM_FF_WINDOW - 1; ++j) line[j] = line[j + 1];
        line[CLM_FF_WINDOW - 1] = in;
        (void)clm_ff_stream_step(&s, in, &out[4 * k + 2]);
        out[4 * k + 3] = fb_line[0];                          /* g(k - LEAD) */
        for (j = 0; j < CLM_FF_LEAD - 1; ++j) fb_line[j] = fb_line[j + 1];
        fb_line[CLM_FF_LEAD - 1] = in;                        /* a delay of LEAD cycles */
    }
    f = fopen(argv[2], "wb");
    fwrite(out, sizeof(double), 4 * (size_t)n, f);
    fclose(f);
    return 0;
}
"""


@needs_cc
@pytest.mark.parametrize("name", ["lip", "pgnn"])
def test_integration_recipes_align_the_force_with_its_sample(name, fitted, effects_lip,
                                                             references, tmp_path):
    """A C harness that emulates the recipes' delay semantics: the Tapped Delay set as the docs
    say (current input included, oldest first, rest as initial condition) gives u_ff[k] at
    sample k; without the current input it is one sample late (the pitfall the docs warn of);
    the PLC task's stream force at cycle k belongs to the sample its feedback reference is."""
    import subprocess
    model, wf = _model(name, fitted, effects_lip)
    c_source.write(wf, tmp_path)
    (tmp_path / "recipes.c").write_text(RECIPES)
    exe = tmp_path / "recipes"
    subprocess.run([compiler(), "-std=c99", "-O2", "-I", str(tmp_path), "-o", str(exe),
                    str(tmp_path / "recipes.c"), str(tmp_path / "clm_ff.c"), "-lm"], check=True)
    r = references["r2"]
    r.astype("<f8").tofile(tmp_path / "r.bin")
    subprocess.run([str(exe), str(tmp_path / "r.bin"), str(tmp_path / "out.bin")], check=True)
    tapped, late, plc, fb_ref = np.fromfile(tmp_path / "out.bin", "<f8").reshape(-1, 4).T
    want = model.feedforward(r, TS)
    assert _rel(tapped, want) < REL
    assert _rel(late[1:], want[:-1]) < REL and _rel(late, want) > 1e-3
    assert np.array_equal(fb_ref, r)  # the feedback sees r[k] in cycle k ...
    assert _rel(plc, want) < REL      # ... and the feedforward is u_ff[k]


def test_filter_kernel_is_the_direct_autocorrelation_and_refuses_a_response_of_seconds():
    """The exported kernel is sosfiltfilt's impulse response: the autocorrelation of the
    forward response, bit for bit (subnormal tail values are flushed only for speed); a cut-off
    whose response lasts longer than the exported limit is refused before the O(n^2) work (a
    1 Hz filter at 10 kHz took 30 s and wrote 12 MB of C)."""
    import scipy.signal

    from controllers.export.window import MAX_RESPONSE_S

    ts, cutoff = 1e-4, 100.0
    kernel = filtfilt_kernel(4, cutoff, ts)
    impulse = np.zeros(1 << 14)
    impulse[0] = 1.0
    g = scipy.signal.sosfilt(scipy.signal.butter(4, cutoff, fs=1 / ts, output="sos"), impulse)
    full = np.correlate(g, g, mode="full")
    mid, m = len(g) - 1, len(kernel) // 2
    assert np.array_equal(kernel, full[mid - m:mid + m + 1])
    with pytest.raises(UserError, match=f"does not decay within {MAX_RESPONSE_S:g} s"):
        filtfilt_kernel(4, 1.0, ts)
