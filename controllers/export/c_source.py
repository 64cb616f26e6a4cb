"""C99 source of a :class:`~controllers.export.window.WindowFeedforward`: clm_ff.h, clm_ff.c.

Standard C99 and ``<math.h>`` only, no dynamic memory, every weight a ``static const``, no
mutable globals (the streaming form keeps its state in a struct the caller owns). The
feedforward ``clm_ff_real clm_ff(const clm_ff_pos *r)`` (both types double by default) reads ``r[-CLM_FF_LAG] .. r[CLM_FF_LEAD]`` around
the sample ``r[0]`` it is called for and returns the held force of that sample (N).

The filtered features of a PGNN: ``clm_ff`` differences the window in the product's order and
applies the filter's FIR at the two instants the held average needs (``k`` and ``k+1``) in one
pass of eight sums. The streaming form runs the forward half of the filter as its recursion and
only the backward half as an FIR, and keeps ``p[k+1]`` for the next call (about half the work).
Beside the portable C, the PGNN's sums and network have a second path with AVX2 and FMA
intrinsics (GCC or Clang on x86-64), taken per call where the CPU has both, so that the ``-O2``
build anyone compiles runs four doubles per instruction instead of SSE2's two
(``-DCLM_FF_PORTABLE`` leaves it out). ``-DCLM_FF_FLOAT`` is a build for an FPU without double
precision: the reference is an int64 fixed-point position (counts of ``CLM_FF_COUNT_M`` m, set by
``--count-m``), differenced exactly in integers, and every other value is a float (the weights
decimal literals rounded once to float; portable path); docs/export.md states its error.

The streaming form, the status and the limits are in :mod:`controllers.export.c_stream`, the
names and ``--prefix`` in :mod:`controllers.export.c_names`, the self-test in
:mod:`controllers.export.selftest`.
"""

from __future__ import annotations

import numpy as np

from controllers.export import selftest
from controllers.export.c_law import activation_c, effect_c, rigid_body_c
from controllers.export.c_literals import c_array, c_matrix, c_real
from controllers.export.c_names import prefixed
from controllers.export.c_reserved import check_names
from controllers.export.c_runtime import runtime, template
from controllers.export.c_stream import GENERIC_STREAM, STREAM_COMMON, fast_stream
from controllers.export.options import ExportOptions, safe_text
from controllers.export.window import DEFAULT_TOL, WindowFeedforward


def _c_double(x: float) -> str:
    """A double literal that reads back to the same bits (no ``R()``)."""
    text = repr(float(x))
    return text if ("e" in text or "." in text) else text + ".0"


def _limit(x) -> str:
    return "HUGE_VAL" if x is None else _c_double(x)


def _comment_lines(text: str, width: int = 90) -> str:
    """``text`` (already safe) wrapped into `` *   `` comment lines."""
    wrapped, line = [], ""
    for word in text.replace("*/", "* /").split(" "):
        if len(line) + len(word) > width:
            wrapped.append(line.rstrip())
            line = ""
        line += word + " "
    wrapped.append(line.rstrip())
    return "\n".join(f" *   {w}" for w in wrapped)


_SOURCE_HEAD = runtime("source_head.c")  # the file's first comment and its includes
_PRELUDE = runtime("prelude.c")
_LIP_CLM_FF = runtime("lip_clm_ff.c")  # the LIP's clm_ff: its held force from two instants

def header(wf: WindowFeedforward, options: "ExportOptions | None" = None) -> str:
    """``clm_ff.h``: the contract (window, units, model, status) and the declarations (names
    ``clm_ff``/``CLM_FF`` as written here; :func:`write` puts the prefix in)."""
    opt = options or ExportOptions()
    model = _comment_lines(safe_text(wf.describe()))
    trace = _comment_lines(safe_text(opt.trace_line()))
    nsec = 1
    if wf.network is not None and wf.filter.get("cutoff_hz"):
        nsec = len(wf.forward_filter()[0])
    exact = ("it equals clm_ff to rounding" if wf.filter.get("tol", DEFAULT_TOL) <= DEFAULT_TOL
             else "it equals clm_ff to about the --filter-tail share "
                  f"({wf.filter.get('tol'):.0e}; the FIR cut and the recursion's tail differ)")
    if wf.network is None or not wf.filter.get("cutoff_hz"):
        exact = "it computes clm_ff on its window"
    return template("header.h").substitute(
        exact=exact, model=model, trace=trace, ts=_c_double(wf.ts), lag=wf.lag, lead=wf.lead,
        half=wf.half, nsec=nsec, max_force=_limit(opt.max_force), max_slew=_limit(opt.max_slew),
        count_m=_c_double(opt.count_m), envelope=safe_text(opt.envelope),
        r_min=_c_double(-1e6 if opt.r_min is None else opt.r_min),
        r_max=_c_double(1e6 if opt.r_max is None else opt.r_max),
        v_max=_limit(opt.v_max), a_max=_limit(opt.a_max))


def source(wf: WindowFeedforward) -> str:
    """``clm_ff.c``: the feedforward, weights as ``static const`` tables (names ``clm_ff``/
    ``CLM_FF`` and file-local ones unprefixed, as written here; :func:`write` prefixes them)."""
    th = wf.theta
    effects = "".join(f"    p += {effect_c(e)};\n" for e in wf.effects)
    physical = template("physical_lip.c").substitute(
        rigid_body=rigid_body_c(th, "a", "v", "SGN(v)", "y"), effects=effects)
    if wf.network is not None:
        # A PGNN: theta on the same (filtered) features the network sees, as fitted.
        physical = template("physical_pgnn.c").substitute(
            rigid_body=rigid_body_c(th, "f[0]", "f[1]", "f[2]", "f[3]"))
    out = [_SOURCE_HEAD, _PRELUDE, "\n", physical]
    if wf.network is None:
        out.append(_LIP_CLM_FF)
    else:
        out.append(_network_source(wf))
    out.append(STREAM_COMMON)
    if wf.network is not None and wf.filter.get("cutoff_hz"):
        out.append(fast_stream(wf))
    else:
        out.append(GENERIC_STREAM)
    return "".join(out)


_RAW_FEATURES = runtime("raw_features.c")

_DIFFERENCE_SCALES = runtime("difference_scales.c")  # 1/ts^2, 1/(2 ts) of the differences


# The filtered features of a PGNN at the instants k and k+1 from the window. Each instant
# r[k-HALF+i] of the window (i = 0 .. 2 HALF + 1) gives the product's differences once; its
# weight is KERNEL[i+1] at k and KERNEL[i] at k+1. The factors 1/ts^2 and 1/(2 ts) multiply the
# sums, not every term (a rounding apart from the product, far below the 1e-12 it is held to).
_FILTERED_FEATURES = runtime("filtered_features.c")

_AVX2_DETECT = runtime("avx2_detect.c")

_FILTERED_FEATURES_AVX2 = runtime("filtered_features_avx2.c")

_FILTERED_CLM_FF = runtime("filtered_clm_ff.c")


# The activations with AVX2 (x: __m256d), through exp_avx2 where they need e^x; an activation
# missing here keeps the portable network on the AVX2 path too.
_ACT_AVX2 = {
    "tanh": "_mm256_sub_pd(one, _mm256_div_pd(two, _mm256_add_pd(one, "
            "exp_avx2(_mm256_add_pd({x}, {x})))))",
    "sigmoid": "_mm256_div_pd(one, _mm256_add_pd(one, exp_avx2(_mm256_sub_pd(zero, {x}))))",
    "silu": "_mm256_div_pd({x}, _mm256_add_pd(one, exp_avx2(_mm256_sub_pd(zero, {x}))))",
    "relu": "_mm256_max_pd({x}, zero)",
}

_EXP_AVX2 = runtime("exp_avx2.c")


# How clm_ff and the stream call the network on the AVX2 path: the vector network where the
# activation has a vector form, else the portable one.
_NETWORK_AVX2_CALLS = runtime("network_avx2_calls.c")

_NETWORK_PORTABLE_CALLS = runtime("network_portable_calls.c")

# The network's functions, portable and with AVX2: templates of the layer loops, whose sizes
# and count are the model's (one block per hidden layer, one output sum per instant).
_NETWORK = template("network.c")
_NETWORK_LAYER = template("network_layer.c")
_NETWORK_AVX2 = template("network_avx2.c")
_NETWORK_AVX2_LAYER = template("network_avx2_layer.c")
_NETWORK_AVX2_OUTPUT = template("network_avx2_output.c")


def _pad4(n: int) -> int:
    return (n + 3) // 4 * 4


def _network_avx2(net) -> str:
    """The network with AVX2: each layer four units at a time, its weights transposed and padded
    to a multiple of four units (zeros), so one unit's inputs are broadcasts and four units'
    weights one load. ``network_avx2`` runs one instant, ``network2_avx2`` two side by side
    (their chains of operations overlap). ``#define NETWORK_AVX2`` names the one-instant form
    (the portable ``network`` where the activation has no vector form here)."""
    if net.activation not in _ACT_AVX2:
        return _NETWORK_PORTABLE_CALLS
    tables = []
    widths = [4] + [len(b) for _, b in net.layers]
    for li, (w, b) in enumerate(net.layers):
        n_in, n_out, n_pad = widths[li], widths[li + 1], _pad4(widths[li + 1])
        wt = np.zeros((n_in, n_pad))
        wt[:, :n_out] = w.T
        bp = np.zeros(n_pad)
        bp[:n_out] = b
        tables.append(f"static const double W{li}T[{n_in}][{n_pad}] = {c_matrix(wt)};\n")
        tables.append(f"static const double B{li}P[{n_pad}] = {c_array(bp)};\n")
    n_last = _pad4(widths[-1])
    wp = np.zeros(n_last)
    wp[:widths[-1]] = net.out_w
    tables.append(f"static const double OUT_WP[{n_last}] = {c_array(wp)};\n")
    exp = _EXP_AVX2 if "exp_avx2" in _ACT_AVX2[net.activation] else ""
    return ("\n#ifdef CLM_FF_AVX2\n" + exp + "\n" + "\n".join(tables).replace("R(", "(")
            + _network_avx2_function(net, widths, "network_avx2", 1)
            + _network_avx2_function(net, widths, "network2_avx2", 2)
            + _NETWORK_AVX2_CALLS + "#endif\n")


def _network_avx2_function(net, widths, name: str, count: int) -> str:
    """C of ``name``: the network with AVX2 at ``count`` instants, statement by statement."""
    inst = range(count)
    last = len(net.layers)
    act = _ACT_AVX2[net.activation]
    hidden = "".join(f"    double h{li + 1}[{count}][{_pad4(widths[li + 1])}];\n"
                     for li in range(last))
    layers = []
    for li in range(last):
        n_in, n_pad = widths[li], _pad4(widths[li + 1])
        start = "".join(f"        __m256d x{b} = _mm256_loadu_pd(B{li}P + o);\n" for b in inst)
        fma = "".join(f"            x{b} = _mm256_fmadd_pd(w, _mm256_broadcast_sd(&h{li}[{b}][j]), "
                      f"x{b});\n" for b in inst)
        store = "".join(f"        _mm256_storeu_pd(h{li + 1}[{b}] + o, "
                        f"{act.format(x=f'x{b}')});\n"
                        for b in inst)
        layers.append(_NETWORK_AVX2_LAYER.substitute(n_pad=n_pad, n_in=n_in, layer=li,
                                                     start=start, fma=fma, store=store))
    args = ", ".join(f"const double f{b}[4]" for b in inst) + ", double out[]"
    norm = "".join(f"        h0[{b}][i] = (f{b}[i] - IN_MEAN[i]) / IN_STD[i];\n" for b in inst)
    outputs = "".join(_NETWORK_AVX2_OUTPUT.substitute(n_pad=_pad4(widths[-1]), last=last, b=b)
                      for b in inst)
    return _NETWORK_AVX2.substitute(count=count, name=name, args=args, hidden=hidden, norm=norm,
                                    layers="".join(layers), outputs=outputs)


def _network_source(wf: WindowFeedforward) -> str:
    m = wf.half
    padded = np.concatenate([[0.0], wf.kernel, [0.0]])  # the FIR with a zero either side
    net = wf.network
    tables = []
    if m > 0:
        tables += [
            _DIFFERENCE_SCALES,
            "/* The feature filter's FIR h[-HALF .. HALF] with a zero either side: the weight of the\n"
            " * instant r[k-HALF+i] is KERNEL[i+1] for the features at k, KERNEL[i] for those at\n"
            " * k+1 (i = 0 .. 2 HALF + 1). */\n"
            f"static const clm_ff_real KERNEL[2 * HALF + 3] = {c_array(padded)};\n"]
    tables += [f"static const clm_ff_real IN_MEAN[4] = {c_array(net.input_mean)};\n",
               f"static const clm_ff_real IN_STD[4] = {c_array(net.input_std)};\n"]
    widths = [4]
    for li, (w, b) in enumerate(net.layers):
        tables.append(f"static const clm_ff_real W{li}[{w.shape[0]}][{w.shape[1]}] = "
                      f"{c_matrix(w)};\n")
        tables.append(f"static const clm_ff_real B{li}[{len(b)}] = {c_array(b)};\n")
        widths.append(w.shape[0])
    tables.append(f"static const clm_ff_real OUT_W[{len(net.out_w)}] = {c_array(net.out_w)};\n")
    tables.append(f"static const clm_ff_real OUT_B = {c_real(net.out_b)};\n")
    layers = "".join(
        _NETWORK_LAYER.substitute(layer=li, next=li + 1, n_in=widths[li], n_out=widths[li + 1],
                                  activation=activation_c(net.activation))
        for li in range(len(net.layers)))
    network = "\n" + "\n".join(tables) + _NETWORK.substitute(
        layers=layers, n_last=widths[-1], last=len(net.layers),
        closing="    }\n" * len(net.layers))
    if m == 0:
        return network + _RAW_FEATURES
    return (_AVX2_DETECT + network + _network_avx2(net) + _FILTERED_FEATURES
            + _FILTERED_FEATURES_AVX2 + _FILTERED_CLM_FF)


def write(wf: WindowFeedforward, folder, options: ExportOptions | None = None) -> list:
    """Write ``<prefix>.h``, ``<prefix>.c``, the self-test ``<prefix>_selftest.c`` and its
    vectors ``<prefix>_kat.csv`` into ``folder``; returns the paths."""
    from pathlib import Path

    opt = options or ExportOptions()
    folder = Path(folder)
    paths = [folder / f"{opt.prefix}.h", folder / f"{opt.prefix}.c"]
    texts = [prefixed(header(wf, opt), opt.prefix), prefixed(source(wf), opt.prefix)]
    check_names(texts, opt.prefix)
    paths[0].write_text(texts[0])
    paths[1].write_text(texts[1])
    return paths + selftest.write(wf, folder, opt.prefix, c=True, count_m=opt.count_m,
                                  limits=opt.limits())
