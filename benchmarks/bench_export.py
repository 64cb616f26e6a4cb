"""Time the exported feedforward against the 10 kHz cycle (100 us): C at -O2 and ONNX Runtime.

Fits a LIP and an n_l = 16 PGNN on one pass of r1 (quickly: ``max_iter`` 5; the weights' values
do not change the work per call), exports both, compiles the C with the system compiler and
times ``clm_ff`` and the streaming form over every sample of r2 in blocks of ``--block`` calls
(CPU time of the calling thread), ``--repeats`` passes: the best block is the cost of a call
undisturbed, the median block what a shared machine gave while measuring. The default build
takes the AVX2 path where the CPU has AVX2 and FMA; ``-DCLM_FF_PORTABLE`` is the portable C,
``-DCLM_FF_FLOAT`` the single-precision build (int64 counts in, float arithmetic; its error
against the product on the same counts, and the cost of the rounding to counts). ONNX Runtime is timed per call (batch 1,
``session.run`` included) and batched (``--batch`` windows per run). Also prints the error of
the C against the product's Python feedforward, and what ``export-ff --filter-tail`` trades
(window, look-ahead, error, time) for the values of ``--filter-tails``.

Run from the repository root: ``python benchmarks/bench_export.py``. Last line on stdout:
``<model>_c[_stream][_portable|_float][_median]_ns=<t> ... onnx_call_us=<t> onnx_batched_ns=<t>
onnx_mlp_call_us=<t>``
(``<model>``: lip, pgnn16; without ``_median``: the best block).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from clm_sim.loop import simulate  # noqa: E402
from controllers.export import c_source  # noqa: E402
from controllers.export.cbuild import CompiledFeedforward, compiler  # noqa: E402
from controllers.export.window import from_lip, from_pgnn  # noqa: E402
from experiments.config import ExperimentConfig, Training  # noqa: E402
from experiments.testbed import Testbed  # noqa: E402

CYCLE_NS = 100e3


def _rel(got, want) -> float:
    return float(np.max(np.abs(got - want)) / np.max(np.abs(want)))


def _filter_tails(tb, pgnn, r, args, results) -> None:
    """The cut of the feature filter (``export-ff --filter-tail``) against the window, the
    look-ahead, the error against the product, the closed-loop MAE on r2 with the exported
    feedforward, and the time per call."""
    ts = tb.ts
    want = pgnn.feedforward(r, ts)
    mae = tb.replay(pgnn, r).mae
    print(f"pgnn{args.hidden}, --filter-tail: window, look-ahead, error vs Python (of the peak "
          f"force, streaming form on r2), r2 MAE in closed loop with it (Python's "
          f"{1e6 * mae:.5f} um), clm_ff and streaming ns (best block)", file=sys.stderr)
    for tail in args.filter_tails:
        wf = from_pgnn(pgnn, ts, "bench", tol=tail)
        with tempfile.TemporaryDirectory() as tmp:
            c_source.write(wf, tmp)
            lib = CompiledFeedforward(tmp, tuple(args.flags.split()))
            u_ff = lib.stream(r)
            err = _rel(u_ff, want)
            mae_c = simulate(tb.machine, tb.pid, r, ts, u_ff=u_ff).mae
            ns = float(np.min(lib.time_blocks(r, args.repeats, args.block)))
            ns_stream = float(np.min(lib.time_blocks(r, args.repeats, args.block, stream=True)))
        results[f"tail_{tail:.0e}_err"] = err
        print(f"  {tail:.0e}: {wf.lag}+1+{wf.lead} samples, look-ahead {1e3 * wf.lead * ts:.1f} "
              f"ms, error {err:.1e}, MAE {1e6 * mae_c:.5f} um ({(mae_c - mae) / mae:+.1e}), "
              f"clm_ff {ns:,.0f} ns, streaming {ns_stream:,.0f} ns", file=sys.stderr)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeats", type=int, default=3, help="passes over r2 (default 3)")
    p.add_argument("--block", type=int, default=256,
                   help="calls per timed block (default 256): the best block is the cost of a "
                        "call undisturbed, the median what a shared machine gives")
    p.add_argument("--batch", type=int, default=1000)
    p.add_argument("--hidden", type=int, default=16)
    p.add_argument("--flags", default="-O2", help="C compiler flags (default -O2)")
    p.add_argument("--filter-tails", type=float, nargs="*",
                   default=[1e-15, 1e-12, 1e-9, 1e-6, 1e-3],
                   help="export-ff --filter-tail values to compare (none: skip)")
    args = p.parse_args(argv)
    tb = Testbed(ExperimentConfig(training=Training(repeats=1)))
    run = tb.training_run()
    lip = tb.fit_lip(run)
    pgnn = tb.fit_pgnn(run, hidden=args.hidden, lip=lip, max_iter=5)
    r = tb.reference("r2")
    results = {}
    if compiler() is None:
        print("no C compiler: C not timed", file=sys.stderr)
    for name, model, wf in (("lip", lip, from_lip(lip, tb.ts, "bench")),
                            (f"pgnn{args.hidden}", pgnn, from_pgnn(pgnn, tb.ts, "bench"))):
        if compiler() is None:
            break
        with tempfile.TemporaryDirectory() as tmp:
            c_source.write(wf, tmp)
            lib = CompiledFeedforward(tmp, tuple(args.flags.split()))
            portable = CompiledFeedforward(tmp, (*args.flags.split(), "-DCLM_FF_PORTABLE"))
            single = CompiledFeedforward(tmp, (*args.flags.split(), "-DCLM_FF_FLOAT"))
            want = model.feedforward(r, tb.ts)
            err = _rel(lib.stream(r), want)
            # the float build reads int64 counts: its own error against the product on the
            # same counts, and apart from it what the rounding to counts costs (max, RMS)
            rq = single.quantized(r)
            want_q = model.feedforward(rq, tb.ts)
            err32 = _rel(single.stream(r), want_q)
            k32 = np.arange(0, len(r), 13)
            err32_call = _rel(single(wf.windows(r)[k32]), want_q[k32])
            quant = _rel(want_q, want)
            quant_rms = float(np.sqrt(np.mean((want_q - want) ** 2)) / np.max(np.abs(want)))
            results[f"{name}_float_err"] = err32
            results[f"{name}_float_call_err"] = err32_call
            err_portable = _rel(portable.stream(r), want)
            k = np.arange(0, len(r), 13)  # the stateless call on every 13th window
            w = wf.windows(r)[k]
            err_call = max(_rel(lib(w[i:i + 2048]), want[k][i:i + 2048]) for i in
                           range(0, len(k), 2048))
            timed = {"": lib, "_portable": portable, "_float": single}
            for build, compiled in timed.items():
                for form, stream in (("", False), ("_stream", True)):
                    ns = compiled.time_blocks(r, args.repeats, args.block, stream=stream)
                    results[f"{name}_c{form}{build}_ns"] = float(np.min(ns))
                    results[f"{name}_c{form}{build}_median_ns"] = float(np.median(ns))
        t = {k[len(name) + 1:]: v for k, v in results.items() if k.startswith(name + "_")}
        print(f"{name}: window {wf.lag}+1+{wf.lead} samples; C {args.flags}, ns per call, best "
              f"block (median block): clm_ff {t['c_ns']:,.0f} ({t['c_median_ns']:,.0f}), "
              f"streaming {t['c_stream_ns']:,.0f} ({t['c_stream_median_ns']:,.0f}); "
              f"-DCLM_FF_PORTABLE clm_ff {t['c_portable_ns']:,.0f} "
              f"({t['c_portable_median_ns']:,.0f}), streaming {t['c_stream_portable_ns']:,.0f} "
              f"({t['c_stream_portable_median_ns']:,.0f}); -DCLM_FF_FLOAT clm_ff "
              f"{t['c_float_ns']:,.0f}, streaming {t['c_stream_float_ns']:,.0f}; against the "
              f"100 us cycle: clm_ff {100 * t['c_ns'] / CYCLE_NS:.2f} %. Error vs Python "
              f"{err_call:.1e} (clm_ff), {err:.1e} (streaming), {err_portable:.1e} (portable "
              f"streaming) of the peak force. -DCLM_FF_FLOAT (int64 counts of "
              f"{single.count_m:g} m, float arithmetic) against the product on the same counts: "
              f"{err32_call:.1e} (clm_ff), {err32:.1e} (streaming); the rounding to counts "
              f"itself moves the product's force by {quant:.1e} (max; RMS {quant_rms:.1e})",
              file=sys.stderr)
    if compiler() is not None and args.filter_tails:
        _filter_tails(tb, pgnn, r, args, results)
    try:
        import onnxruntime as ort

        from controllers.export import onnx_graph
    except ImportError:
        print("onnxruntime not installed (pip install 'clm-sim[export]'): ONNX not timed",
              file=sys.stderr)
    else:
        wf = from_pgnn(pgnn, tb.ts, "bench")
        with tempfile.TemporaryDirectory() as tmp:
            onnx_graph.write(wf, tmp)
            opts = ort.SessionOptions()
            opts.intra_op_num_threads = 1
            sess = ort.InferenceSession(str(Path(tmp) / "clm_ff.onnx"), opts,
                                        providers=["CPUExecutionProvider"])
        windows = np.ascontiguousarray(wf.windows(r)[20000:20000 + args.batch])
        one = [np.ascontiguousarray(windows[i:i + 1]) for i in range(min(200, len(windows)))]
        sess.run(["u_ff"], {"r_window": one[0]})
        calls = []
        for _ in range(args.repeats):
            t0 = time.process_time()
            for w in one:
                sess.run(["u_ff"], {"r_window": w})
            calls.append((time.process_time() - t0) / len(one) * 1e9)
        batched = []
        for _ in range(args.repeats):
            t0 = time.process_time()
            sess.run(["u_ff"], {"r_window": windows})
            batched.append((time.process_time() - t0) / len(windows) * 1e9)
        results["onnx_call_us"] = min(calls) / 1e3
        results["onnx_batched_ns"] = min(batched)
        with tempfile.TemporaryDirectory() as tmp:  # the plain-MLP form: features in
            onnx_graph.mlp_write(wf, tmp)
            mlp = ort.InferenceSession(str(Path(tmp) / "clm_ff.onnx"), opts,
                                       providers=["CPUExecutionProvider"])
        feats = [np.ascontiguousarray(wf.features(w[None, :-1])) for w in windows[:200]]
        mlp.run(["force"], {"features": feats[0]})
        mlp_calls = []
        for _ in range(args.repeats):
            t0 = time.process_time()
            for f in feats:
                mlp.run(["force"], {"features": f})
            mlp_calls.append((time.process_time() - t0) / len(feats) * 1e9)
        results["onnx_mlp_call_us"] = min(mlp_calls) / 1e3
        print(f"pgnn{args.hidden}: ONNX Runtime {ort.__version__} (1 thread): "
              f"{min(calls) / 1e3:,.1f} us per call (batch 1, {100 * min(calls) / CYCLE_NS:.1f} % "
              f"of the cycle), {min(batched):,.0f} ns per window in batches of {len(windows)}; "
              f"the plain-MLP form (--onnx-form mlp, features in) {min(mlp_calls) / 1e3:,.1f} us "
              f"per call (one instant; the held average needs two)", file=sys.stderr)
    print(" ".join(f"{k}={v:.4g}" for k, v in results.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
