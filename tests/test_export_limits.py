"""The export as shipped: limits from the data the model was fitted on, one check of a bad sample,
a stream that says when it has no window, limits that survive a restart, a self-test free of the
limits, no spike from a rejected sample in motion, models and options that make no sense refused,
and every C recipe of docs/export.md and docs/export_targets.md compiled and run against the double and the float build.

Oracle: the window form (:class:`~controllers.export.window.WindowFeedforward`), which
tests/test_export.py holds to the product's feedforward; inside the envelope the default build
must give exactly what the unlimited one gives.
"""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest
from test_export import (  # noqa: F401  (fixtures)
    REL,
    TS,
    _padded,
    _rel,
    fitted,
    needs_cc,
    references,
    testbed,
    training_run,
)

from clm_sim.records.write import save_npz
from controllers.export import selftest
from controllers.export.cbuild import CompiledFeedforward, compiler
from controllers.export.envelope import MARGIN, Envelope
from controllers.export.window import from_lip, from_pgnn
from experiments.cli import main

OK, REJECTED, DEGRADED, CLAMPED, SLEWED, STOPPED = 0, 1, 2, 4, 8, 16
DOCS = [Path(__file__).resolve().parents[1] / "docs" / name
        for name in ("export.md", "export_targets.md")]


@pytest.fixture(scope="module")
def shipped(fitted, training_run, tmp_path_factory):
    """The LIP and the n_l = 16 PGNN exported as a user does, by default (limits from the
    training record, given by --limits-from as the models are saved alone here), and their
    window forms."""
    folder = tmp_path_factory.mktemp("shipped")
    save_npz(training_run, folder / "train.npz")
    fitted["lip"].save(folder / "lip.json")
    fitted["pgnn"].save(folder / "pgnn")
    out = {"record": folder / "train.npz", "folder": folder}
    for name, model in (("lip", "lip.json"), ("pgnn", "pgnn.pt")):
        assert main(["export-ff", str(folder / model), "--to", "c", "--out", str(folder / name),
                     "--ts", str(TS), "--limits-from", str(folder / "train.npz")]) == 0
        make = from_lip if name == "lip" else from_pgnn
        out[name] = (folder / name, make(fitted[name], TS, "test"))
    return out


def _limits(folder: Path) -> dict:
    return json.loads((folder / "export.json").read_text())


@pytest.mark.parametrize("name", ["lip", "pgnn"])
def test_default_limits_are_the_training_envelope_with_its_margin(name, shipped, training_run):
    """export.json and the header carry the data's envelope widened by MARGIN: positions,
    velocity and acceleration as the fit saw them (through the model's 250 Hz regression
    filter), the applied force."""
    folder, _ = shipped[name]
    info = _limits(folder)
    env = Envelope.of_record(training_run.y, training_run.u, TS, "train.npz", 250.0, 4)
    want = env.limits()
    for key in ("max_force", "r_min", "r_max", "v_max", "a_max"):
        assert info[key] == pytest.approx(want[key], rel=1e-12), key
    assert info["max_force"] == pytest.approx((1 + MARGIN) * np.max(np.abs(training_run.u)))
    assert info["max_slew"] is None and "train.npz" in info["limits_from"]
    header = (folder / "clm_ff.h").read_text()
    assert f"#define CLM_FF_MAX_FORCE {info['max_force']!r}" in header
    assert f"#define CLM_FF_A_MAX {info['a_max']!r}" in header


@needs_cc
@pytest.mark.parametrize("build", ["", "-DCLM_FF_FLOAT"])
@pytest.mark.parametrize("name", ["lip", "pgnn"])
def test_the_default_build_changes_nothing_inside_and_bounds_everything_outside(
        name, build, shipped, references):
    """Inside the envelope (r2: the product's own validation reference) the default build gives
    the unlimited force with status 0; a sample of 1e5 m is rejected, not a force of 1e10 N; a
    reference three times as fast is cut (CLAMPED) and never beyond the force limit; the
    stateless call refuses a window holding 1e200 m."""
    folder, wf = shipped[name]
    info = _limits(folder)
    c = CompiledFeedforward(folder, ("-O2", build) if build else ("-O2",))
    unlimited = ("-DCLM_FF_MAX_FORCE=HUGE_VAL", "-DCLM_FF_V_MAX=HUGE_VAL",
                 "-DCLM_FF_A_MAX=HUGE_VAL", "-DCLM_FF_R_MIN=-1e6", "-DCLM_FF_R_MAX=1e6")
    free = CompiledFeedforward(folder, ("-O2", *([build] if build else []), *unlimited))
    r = references["r2"]
    u, st, init = c.stream_status(_padded(wf, r))
    u_free, _, _ = free.stream_status(_padded(wf, r))
    assert init == OK and not st.any()
    assert np.array_equal(u, u_free)  # the function replayed is the function fitted
    assert _rel(u, wf.apply(c.quantized(r))) < (REL if not build else 1e-4)
    k = np.arange(0, len(r), 1009)
    ue, ste = c.eval(wf.windows(r)[k])
    assert not ste.any() and np.array_equal(ue, free(wf.windows(r)[k]))
    bad = _padded(wf, r)
    bad[wf.lag + 5000] = 1e5
    u, st, _ = c.stream_status(bad)
    assert st[5000 - wf.lead] & REJECTED and np.max(np.abs(u)) <= info["max_force"]
    w = wf.windows(r)[6000:6001].copy()
    w[0, wf.lag] = 1e200
    assert c.eval(w)[1][0] == REJECTED
    fast = r[::3]  # the same path in a third of the time: 3x the speed, 9x the acceleration
    u, st, _ = c.stream_status(_padded(wf, fast))
    assert (st & CLAMPED).any() and np.max(np.abs(u)) <= info["max_force"]


@needs_cc
@pytest.mark.parametrize("build", ["", "-DCLM_FF_FLOAT"])
def test_the_stream_and_the_stateless_call_agree_on_a_bad_sample(build, shipped):
    """One check for both: each value in a window of clm_ff_eval is rejected exactly when the
    same value pushed into the stream is (values at and beside the envelope's ends, far beyond
    it, not finite)."""
    folder, wf = shipped["lip"]
    info = _limits(folder)
    c = CompiledFeedforward(folder, ("-O2", build) if build else ("-O2",))
    lo, hi = info["r_min"], info["r_max"]
    mid = 0.5 * (lo + hi)
    values = [mid, lo, hi, lo + 1e-9, hi - 1e-9, lo - 1e-6, hi + 1e-6, np.nextafter(hi, 1.0),
              2 * hi - lo, -1e5, 1e200, -1e300, np.nan, np.inf, -np.inf]
    for x in values:
        w = np.full((1, wf.width), mid)
        w[0, wf.lag + 1] = x
        eval_rejected = bool(c.eval(w)[1][0] & REJECTED)
        rp = np.full(wf.lag + 40 + wf.lead, mid)
        rp[wf.lag + 20] = x
        _, st, _ = c.stream_status(rp)
        stream_rejected = bool(np.any(st & REJECTED))
        assert eval_rejected == stream_rejected, x
        assert eval_rejected == (not (lo <= x <= hi) or not np.isfinite(x)) or build, x


@needs_cc
@pytest.mark.parametrize("name", ["lip", "pgnn"])
def test_a_rejected_init_or_start_says_so_until_a_good_start(name, shipped, references):
    """Init on a NaN (or a window holding one): every push returns 0 N with REJECTED | STOPPED,
    never a silent status 0; a good start afterwards gives the product's force again."""
    folder, wf = shipped[name]
    c = CompiledFeedforward(folder)
    r = references["r2"]
    rp = _padded(wf, r)
    rp[0] = np.nan
    u, st, init = c.stream_status(rp)
    assert init == REJECTED | STOPPED
    assert np.all(st == REJECTED | STOPPED) and np.all(u == 0.0)
    k0 = 5000 + wf.width  # a window clear of the NaN: the start recovers the stream
    u, st, init = c.stream_status(rp, start=k0, restart=True)
    assert init == REJECTED | STOPPED  # the init's; the start itself is OK
    assert not st[k0 + 1:].any()
    assert _rel(u[k0:], wf.apply(r)[k0:]) < REL


@needs_cc
@pytest.mark.parametrize("name", ["lip", "pgnn"])
def test_limits_set_at_run_time_survive_init_and_start(name, shipped, references):
    """clm_ff_stream_limits before init, and between init and a start on a moving reference:
    neither start call puts the export's limits back."""
    folder, wf = shipped[name]
    c = CompiledFeedforward(folder)
    r = references["r2"]
    free, _, _ = c.stream_status(_padded(wf, r))
    cap = 0.3 * np.max(np.abs(free))
    u, st, _ = c.stream_status(_padded(wf, r), max_force=cap, max_slew=1e9, limits_first=True)
    assert np.max(np.abs(u)) <= cap and (st & CLAMPED).any()
    k0 = int(np.argmax(np.abs(np.gradient(r))))
    u, st, _ = c.stream_status(_padded(wf, r), start=k0, max_force=cap, max_slew=1e9,
                               restart=True)
    assert np.max(np.abs(u[k0 + 1:])) <= cap and (st[k0 + 1:] & CLAMPED).any()


@needs_cc
@pytest.mark.parametrize("build", ["", "-DCLM_FF_FLOAT"])
@pytest.mark.parametrize("name", ["lip", "pgnn"])
def test_a_rejected_sample_in_motion_is_extrapolated_not_a_spike(name, build, shipped,
                                                                  references):
    """A NaN pushed where r2 is fastest, where it accelerates most and where its jerk is
    largest: the sample put in its place continues the motion at constant acceleration, so the
    force stays the clean one to the extrapolation's error (LIP: measured 1.1e-2 of the peak at
    the largest jerk, held to 3e-2; PGNN, whose filter smooths it: 3e-13, held to 1e-9), and
    within the peak; four in a row: LIP 0.27 measured, held to 0.5."""
    folder, wf = shipped[name]
    c = CompiledFeedforward(folder, ("-O2", build) if build else ("-O2",))
    r = references["r2"]
    rp = _padded(wf, r)
    clean, _, _ = c.stream_status(rp)
    peak = np.max(np.abs(clean))
    a, j = np.diff(r, 2), np.diff(r, 3)
    for where in (int(np.argmax(np.abs(np.gradient(r)))), int(np.argmax(np.abs(a))) + 1,
                  int(np.argmax(np.abs(j))) + 1):
        for burst, bound in ((1, 3e-2), (4, 0.5)):
            bad = rp.copy()
            bad[wf.lag + where + wf.lead:wf.lag + where + wf.lead + burst] = np.nan
            u, st, _ = c.stream_status(bad)
            assert st[where] & REJECTED
            err = np.max(np.abs(u - clean)) / peak
            assert err < (bound if name == "lip" else 1e-9), (where, burst, err)
            assert np.max(np.abs(u)) <= (1 + bound) * peak


def _lip_file(folder: Path, fitted, **edits) -> Path:
    data = json.loads(json.dumps(fitted["lip"].to_json()))  # a copy: to_json shares coef_
    for key, value in edits.items():
        data[key] = value
        data["coefficients"][key] = value
    path = folder / ("lip_" + "_".join(f"{k}{v:g}" for k, v in edits.items()) + ".json")
    path.write_text(json.dumps(data))
    return path


@pytest.mark.parametrize("edits", [{"mass": 2e4}, {"viscous": 3e5}, {"coulomb": 1e5},
                                   {"stiffness": 1e12}, {"mass": 1e200}, {"mass": 1.7e308}])
def test_a_model_absurd_for_its_data_is_refused(edits, shipped, fitted, tmp_path, capsys):
    """Held-back variants of a parameter in the wrong unit: forces of more than ten times the
    data's largest on a motion inside its envelope, or not finite: one line, exit 2, nothing
    written. The true model exports."""
    path = _lip_file(tmp_path, fitted, **edits)
    out = tmp_path / "out"
    code = main(["export-ff", str(path), "--to", "c", "--out", str(out), "--limits-from",
                 str(shipped["record"])])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and ("not a fit" in err[0] or "not finite" in err[0])
    assert not out.exists()


@pytest.mark.parametrize("count_m, ok", [(1e-9, True), (1e-6, False), (3e-4, False),
                                         (1e-40, False)])
def test_a_count_that_leaves_the_self_test_nothing_to_test_is_refused(count_m, ok, shipped,
                                                                      tmp_path, capsys):
    code = main(["export-ff", str(shipped["folder"] / "lip.json"), "--to", "c", "--out",
                 str(tmp_path / "out"), "--limits-from", str(shipped["record"]),
                 "--count-m", repr(count_m)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == (0 if ok else 2)
    if not ok:
        assert len(err) == 1 and "--count-m" in err[0] and not (tmp_path / "out").exists()


@pytest.mark.parametrize("prefix, ok", [
    ("sqrt", False), ("class", False), ("y1", False), ("memx", False), ("lgammaf", False),
    ("ax_stream_push", False), ("ax_real", False), ("ax_pos", False), ("motor_selftest", False),
    ("axis_x", True), ("motor_ts", True), ("ax_w0", True), ("gantry2", True)])
def test_a_prefix_meeting_c_names_or_another_export_is_refused(prefix, ok, shipped, tmp_path,
                                                               capsys):
    """Held-back names: a libm function, a C++ keyword, a POSIX libm name, a name the standard
    reserves, and prefixes that nest in another export's (``ax`` defines ``ax_stream_push``)."""
    code = main(["export-ff", str(shipped["folder"] / "pgnn.pt"), "--to", "c", "--out",
                 str(tmp_path / "out"), "--limits-from", str(shipped["record"]),
                 "--prefix", prefix])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == (0 if ok else 2), err
    if not ok:
        assert len(err) == 1 and err[0].startswith(f"clm-sim: error: --prefix {prefix}")
        assert not (tmp_path / "out").exists()


# -- the recipes of docs/export.md -------------------------------------------------------------
SIMSTRUC = r"""
/* A stand-in for Simulink's simstruc.h: what the recipe's S-function calls. */
typedef double real_T;
typedef int int_T;
typedef struct { const real_T *in; real_T *out; int width; double ts; } SimStruct;
#define ssSetNumSFcnParams(S, n) ((void)(S), (void)(n))
#define ssSetNumInputPorts(S, n) ((void)(n), (S) != 0)
#define ssSetInputPortWidth(S, p, w) ((void)(p), (S)->width = (w))
#define ssSetInputPortDirectFeedThrough(S, p, d) ((void)(S), (void)(p), (void)(d))
#define ssSetInputPortRequiredContiguous(S, p, c) ((void)(S), (void)(p), (void)(c))
#define ssSetNumOutputPorts(S, n) ((void)(n), (S) != 0)
#define ssSetOutputPortWidth(S, p, w) ((void)(S), (void)(p), (void)(w))
#define ssSetNumSampleTimes(S, n) ((void)(S), (void)(n))
#define ssSetSampleTime(S, i, t) ((void)(i), (S)->ts = (t))
#define ssSetOffsetTime(S, i, t) ((void)(S), (void)(i), (void)(t))
#define ssGetInputPortRealSignal(S, p) ((void)(p), (S)->in)
#define ssGetOutputPortRealSignal(S, p) ((void)(p), (S)->out)
"""

DRIVER = r"""
#include <stdio.h>
#include <stdlib.h>
#include <math.h>
#include "recipe.c"
/* argv[1]: n doubles r (m); argv[2]: n doubles u_ff (N), the reference held at its ends. */
#ifdef CLM_FF_FLOAT
#define P(x) ((clm_ff_pos)llround((x) / CLM_FF_COUNT_M))
#else
#define P(x) (x)
#endif
static long n;
static double *r;
static double at(long k) { return r[k < 0 ? 0 : (k >= n ? n - 1 : k)]; }
int main(int argc, char **argv)
{
    FILE *f = fopen(argv[1], "rb");
    double *u;
    long k;
    if (argc != 3 || !f) return 2;
    fseek(f, 0, SEEK_END);
    n = ftell(f) / (long)sizeof(double);
    rewind(f);
    r = malloc(sizeof(double) * (size_t)n);
    u = malloc(sizeof(double) * (size_t)n);
    if (fread(r, sizeof(double), (size_t)n, f) != (size_t)n) return 2;
    fclose(f);
    RUN
    f = fopen(argv[2], "wb");
    fwrite(u, sizeof(double), (size_t)n, f);
    fclose(f);
    return 0;
}
"""

RUNS = {
    "mdlOutputs": """{
        static real_T in[CLM_FF_WINDOW];
        real_T y;
        SimStruct S;
        long j;
        mdlInitializeSizes(&S);
        mdlInitializeSampleTimes(&S);
        if (S.width != CLM_FF_WINDOW || S.ts != CLM_FF_TS) return 3;
        S.in = in;
        S.out = &y;
        for (k = 0; k < n; ++k) {
            for (j = 0; j < CLM_FF_WINDOW; ++j) in[j] = at(k - CLM_FF_LAG + j);
            mdlOutputs(&S, 0);
            u[k] = y;
        }
        mdlTerminate(&S);
    }""",
    "axis_cycle": """{
        static Axis ax;
        if (axis_start(&ax, P(at(0))) != 0) return 4;  /* the axis is not enabled */
        for (k = -CLM_FF_LEAD; k < n; ++k) {
            const double x = (double)axis_cycle(&ax, P(at(k + CLM_FF_LEAD)));
            if (k >= 0) u[k] = x;
        }
    }""",
    "ff_cycle": """{
        ff_start(P(at(0)));
        for (k = -CLM_FF_LEAD; k < n; ++k) {
            const double x = (double)ff_cycle(P(at(k + CLM_FF_LEAD)));
            if (k >= 0) u[k] = x;
        }
    }""",
}


def recipes() -> list[str]:
    """The C blocks of the export's pages that are programs' parts (they include the header)."""
    blocks = [b for page in DOCS
              for b in re.findall(r"```c\n(.*?)```", page.read_text(), flags=re.S)]
    return [b for b in blocks if '#include "clm_ff.h"' in b]


def test_the_docs_hold_the_three_recipes():
    found = sorted(key for b in recipes() for key in RUNS if key in b)
    assert found == sorted(RUNS)
    assert not any(re.search(r"\bdouble\b", b) for b in recipes())  # the build's types


@needs_cc
@pytest.mark.parametrize("build", ["", "-DCLM_FF_FLOAT"])
@pytest.mark.parametrize("name", ["lip", "pgnn"])
def test_every_recipe_compiles_and_runs_against_both_builds(name, build, shipped, references,
                                                            tmp_path):
    """Each recipe, as the docs print it, compiled with strict warnings into a program with the
    default export, in the double and the float build, on the self-test's motion (inside the
    envelope, at rest at its ends); its forces are the model's (double: to 1e-9 of the peak;
    float: to the self-test's 1e-4, on the reference in counts). The PLC
    recipe enables its axis (its self-test passes) also with a force limit at a fifth of the
    peak."""
    folder, wf = shipped[name]
    r = selftest.motion(wf, _limits(folder))  # inside the envelope, at rest at both ends
    np.asarray(r, dtype="<f8").tofile(tmp_path / "r.bin")
    (tmp_path / "simstruc.h").write_text(SIMSTRUC)
    (tmp_path / "cg_sfun.h").write_text("/* stand-in */\n")
    flags = ["-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic", "-Wshadow"]
    flags += [build] if build else []
    count_m = 1e-12
    want = wf.apply(np.floor(np.abs(r) / count_m + 0.5) * np.sign(r) * count_m if build else r)
    peak = np.max(np.abs(want))
    for i, block in enumerate(recipes()):
        key = next(k for k in RUNS if k in block)
        for extra in ([], [f"-DCLM_FF_MAX_FORCE={float(0.2 * peak)!r}"]) if key == "axis_cycle" \
                else ([],):
            (tmp_path / "recipe.c").write_text(block)
            (tmp_path / "main.c").write_text(DRIVER.replace("RUN", RUNS[key]))
            exe = tmp_path / f"recipe{i}"
            subprocess.run([compiler(), *flags, *extra, "-I", str(folder), "-I", str(tmp_path),
                            "-o", str(exe), str(tmp_path / "main.c"), str(folder / "clm_ff.c"),
                            str(folder / "clm_ff_selftest.c"), "-lm"], check=True)
            done = subprocess.run([str(exe), str(tmp_path / "r.bin"), str(tmp_path / "u.bin")])
            assert done.returncode == 0, (key, extra)
            if not extra:
                got = np.fromfile(tmp_path / "u.bin", dtype="<f8")
                assert _rel(got, want) < (1e-9 if not build else 1e-4), key
