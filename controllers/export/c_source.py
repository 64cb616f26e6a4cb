"""C99 source of a :class:`~controllers.export.window.WindowFeedforward`: clm_ff.h, clm_ff.c.

Standard C99 and ``<math.h>`` only, no dynamic memory, every weight a ``static const double``,
no mutable globals (the streaming form keeps its state in a struct the caller owns). The
feedforward ``double clm_ff(const double *r)`` reads ``r[-CLM_FF_LAG] .. r[CLM_FF_LEAD]`` around
the sample ``r[0]`` it is called for and returns the held force of that sample (N).

The filtered features of a PGNN: ``clm_ff`` differences the window in the product's order and
applies the filter's FIR at the two instants the held average needs (``k`` and ``k+1``) in one
pass of eight accumulators, which a compiler vectorizes. The streaming form runs the forward half
of the filter as its recursion and only the backward half as an FIR, and keeps ``p[k+1]`` for the
next call (several times faster). ``-DCLM_FF_FLOAT`` makes the arithmetic single precision (the weights stay
decimal literals rounded once to float) for a target without a double-precision FPU.
"""

from __future__ import annotations

import numpy as np

from clm_sim.effects import (
    CableSlab,
    Cogging,
    ForceOffset,
    ForceRipple,
    FrictionAsymmetry,
    Stribeck,
)
from clm_sim.errors import UserError
from controllers.export.window import WindowFeedforward


def _num(x: float) -> str:
    """A double literal that reads back to the same bits, as a ``real`` (float or double)."""
    text = repr(float(x))
    if "e" not in text and "." not in text and "inf" not in text and "nan" not in text:
        text += ".0"
    return f"R({text})"


def _array(values, per_line: int = 4) -> str:
    vals = [_num(v) for v in np.ravel(values)]
    lines = [", ".join(vals[i:i + per_line]) for i in range(0, len(vals), per_line)]
    return "{\n    " + ",\n    ".join(lines) + "\n}"


def _matrix(rows) -> str:
    return "{\n" + ",\n".join("    " + _array(row, 8).replace("\n", "\n    ")
                              for row in rows) + "\n}"


# -- effects as C expressions of y (m), v (m/s) and base (N: the physical force) ---------------
def _effect_c(e) -> str:
    if isinstance(e, Cogging):
        return (f"{_num(e.amplitude)} * SIN(R(2.0) * R({np.pi!r}) * y / {_num(e.period)} "
                f"+ {_num(e.phase)})")
    if isinstance(e, ForceRipple):
        return (f"-{_num(e.amplitude)} * SIN(R(2.0) * R({np.pi!r}) * y / {_num(e.period)} "
                f"+ {_num(e.phase)}) * base")
    if isinstance(e, CableSlab):
        horner = _num(e.coefficients[-1])
        for c in reversed(e.coefficients[:-1]):
            horner = f"({_num(c)} + (y - {_num(e.center)}) * {horner})"
        return horner
    if isinstance(e, Stribeck):
        return (f"{_num(e.peak)} * SGN(v) * EXP(-POW(FABS(v) / {_num(e.velocity)}, "
                f"{_num(e.exponent)}))")
    if isinstance(e, FrictionAsymmetry):
        return (f"(v > R(0.0) ? {_num(e.coulomb_pos)} + {_num(e.viscous_pos)} * v : "
                f"(v < R(0.0) ? -{_num(e.coulomb_neg)} + {_num(e.viscous_neg)} * v : R(0.0)))")
    if isinstance(e, ForceOffset):
        return _num(e.force_n)
    raise UserError(f"export: effect {e.type!r} has no C form")


_ACT = {
    # 1 - 2/(1 + e^2x): one exp instead of libm's expm1-based tanh; its absolute error is a few
    # 1e-16 (what the force sees through the output weights), and no overflow: e^2x = inf -> 1.
    "tanh": "R(1.0) - R(2.0) / (R(1.0) + EXP(R(2.0) * x))",
    "sigmoid": "R(1.0) / (R(1.0) + EXP(-x))",
    "softplus": "(x > R(20.0) ? x : LOG1P(EXP(x)))",
    "silu": "x / (R(1.0) + EXP(-x))",
    "gelu": "R(0.5) * x * (R(1.0) + ERF(x / SQRT(R(2.0))))",
    "relu": "(x > R(0.0) ? x : R(0.0))",
}

_PRELUDE = """\
#ifdef CLM_FF_FLOAT
typedef float clm_ff_real;
#define R(x) ((float)(x))
#define SIN sinf
#define EXP expf
#define POW powf
#define FABS fabsf
#define TANH tanhf
#define LOG1P log1pf
#define ERF erff
#define SQRT sqrtf
#else
typedef double clm_ff_real;
#define R(x) (x)
#define SIN sin
#define EXP exp
#define POW pow
#define FABS fabs
#define TANH tanh
#define LOG1P log1p
#define ERF erf
#define SQRT sqrt
#endif
#define SGN(x) ((clm_ff_real)(((x) > R(0.0)) - ((x) < R(0.0))))
"""


def header(wf: WindowFeedforward) -> str:
    """``clm_ff.h``: the contract (window, units, model) and the declarations."""
    desc = wf.describe().replace("*/", "* /")  # a file name must not close the comment
    wrapped, line = [], ""
    for word in desc.split(" "):
        if len(line) + len(word) > 90:
            wrapped.append(line.rstrip())
            line = ""
        line += word + " "
    wrapped.append(line.rstrip())
    model = "\n".join(f" *   {w}" for w in wrapped)
    nsec = 1
    if wf.network is not None and wf.filter.get("cutoff_hz"):
        nsec = len(wf.forward_filter()[0])
    return f"""\
/* clm_ff.h -- feedforward exported by clm-sim export-ff (do not edit; re-export instead).
 *
 * Contract. Call clm_ff(&r[k]) once per sample k of the reference r (m), sampled every
 * CLM_FF_TS s. It reads r[k-CLM_FF_LAG] .. r[k+CLM_FF_LEAD] (CLM_FF_LAG + 1 + CLM_FF_LEAD
 * samples, so the reference must be known CLM_FF_LEAD samples ahead) and returns the force (N)
 * to hold over sample k, [k*ts, (k+1)*ts): the value clm-sim's replay adds to the feedback at
 * sample k. Everything the product does is inside: the central differences, the physical
 * layer, the effects, the regression filter and the network, and the held average
 * (p[k] + p[k+1])/2 of the forces at the sample instants. Before the first and after the last
 * sample of a motion, pass the reference held at its ends (the machine at rest).
 *
 * No state, no dynamic memory, no mutable globals: reentrant, and safe in any task. Units: r in
 * m, CLM_FF_TS in s, the result in N. The streaming form (clm_ff_stream_*) keeps the window in
 * a ring buffer the caller owns: push the newest sample r[k+CLM_FF_LEAD], get u_ff[k]. For a
 * PGNN it also keeps the forward half of the feature filter as a recursion and the force at
 * k+1 for the next call, which makes it several times faster than clm_ff; it equals clm_ff to
 * rounding once the window has been filled from rest (clm_ff_stream_init).
 *
 * Model:
{model}
 *
 * Compile: C99, link -lm. -DCLM_FF_FLOAT computes in single precision (see docs/export.md for
 * the error that costs).
 */
#ifndef CLM_FF_H
#define CLM_FF_H

#define CLM_FF_TS {wf.ts!r} /* s: sample time */
#define CLM_FF_LAG {wf.lag} /* samples before k read */
#define CLM_FF_LEAD {wf.lead} /* samples after k read */
#define CLM_FF_WINDOW (CLM_FF_LAG + 1 + CLM_FF_LEAD)
#define CLM_FF_HALF {wf.half} /* half-length of the network's feature filter (0: none) */
#define CLM_FF_NSEC {nsec} /* second-order sections of that filter (state of the stream) */

#ifdef __cplusplus
extern "C" {{
#endif

/* Force (N) to hold over sample k; r points at r[k] (m), r[-CLM_FF_LAG..CLM_FF_LEAD] valid. */
double clm_ff(const double *r);

/* Streaming form: state of the caller (one per axis); no allocation. */
typedef struct {{
    double buf[2 * CLM_FF_WINDOW]; /* each sample twice: the window is always contiguous */
    int next;                      /* where the next sample goes, 0 .. CLM_FF_WINDOW-1 */
    /* PGNN: the forward half of the feature filter run recursively (exact), its last
     * CLM_FF_HALF + 1 outputs (twice, contiguous), and the force at the next instant. */
    double zf[4][CLM_FF_NSEC][2];
    double fwd[2 * (CLM_FF_HALF + 1)][4];
    int fnext;
    double p_next;
}} clm_ff_stream;

/* Fill the window with the rest position r0 (m): the machine at rest before the motion. */
void clm_ff_stream_init(clm_ff_stream *s, double r0);

/* Push the newest reference sample r[k + CLM_FF_LEAD] (m); returns u_ff[k] (N). */
double clm_ff_stream_push(clm_ff_stream *s, double r_newest);

#ifdef __cplusplus
}}
#endif
#endif /* CLM_FF_H */
"""


def source(wf: WindowFeedforward) -> str:
    """``clm_ff.c``: the feedforward, weights as ``static const`` tables."""
    th = wf.theta
    effects = "".join(f"    p += {_effect_c(e)};\n" for e in wf.effects)
    physical = f"""\
/* Force (N) at the sample instant of r[0]: physical layer and effects. */
static clm_ff_real physical(const double *r)
{{
    const clm_ff_real y = (clm_ff_real)r[0];
    const clm_ff_real v = (clm_ff_real)((r[1] - r[-1]) / (2.0 * CLM_FF_TS));
    const clm_ff_real a = (clm_ff_real)((r[1] - 2.0 * r[0] + r[-1]) / (CLM_FF_TS * CLM_FF_TS));
    clm_ff_real p = {_num(th['mass'])} * a + {_num(th['viscous'])} * v
        + {_num(th['coulomb'])} * SGN(v) + {_num(th['stiffness'])} * y;
    const clm_ff_real base = p;
    (void)base;
{effects}    return p;
}}
"""
    out = [f"/* clm_ff.c -- generated by clm-sim export-ff; see clm_ff.h for the contract. */\n"
           f'#include "clm_ff.h"\n#include <math.h>\n\n{_PRELUDE}\n{physical}']
    if wf.network is None:
        out.append("""
double clm_ff(const double *r)
{
    return (double)(R(0.5) * (physical(r) + physical(r + 1)));
}
""")
    else:
        out.append(_network_source(wf))
    if wf.network is not None and wf.filter.get("cutoff_hz"):
        out.append(_fast_stream(wf))
    else:
        out.append(_GENERIC_STREAM)
    return "".join(out)


_GENERIC_STREAM = """
void clm_ff_stream_init(clm_ff_stream *s, double r0)
{
    int i;
    for (i = 0; i < 2 * CLM_FF_WINDOW; ++i)
        s->buf[i] = r0;
    s->next = 0;
}

double clm_ff_stream_push(clm_ff_stream *s, double r_newest)
{
    s->buf[s->next] = r_newest;
    s->buf[s->next + CLM_FF_WINDOW] = r_newest;
    s->next = (s->next + 1) % CLM_FF_WINDOW;
    /* The oldest sample is at buf[next]; r[k] is CLM_FF_LAG after it. */
    return clm_ff(&s->buf[s->next + CLM_FF_LAG]);
}
"""


def _fast_stream(wf: WindowFeedforward) -> str:
    """The PGNN's streaming form: forward sections recursively, backward half as an FIR. The
    sections and their state stay in double whatever ``clm_ff_real`` is (a recursion is where
    single precision would accumulate)."""
    sos, zi, g = wf.forward_filter()
    return f"""
static const double SOS[CLM_FF_NSEC][6] = {_matrix(sos).replace("R(", "(")};
static const double SOS_ZI[CLM_FF_NSEC][2] = {_matrix(zi).replace("R(", "(")};
/* Causal impulse response of the sections, run backwards over the next HALF samples. */
static const clm_ff_real BACK[HALF + 1] = {_array(g)};

/* Push raw features x[4] = [a, v, sign v, y] of the newest instant through the sections. */
static void forward(clm_ff_stream *s, const double x[4])
{{
    int c, j;
    for (c = 0; c < 4; ++c) {{
        double xc = x[c];
        for (j = 0; j < CLM_FF_NSEC; ++j) {{ /* transposed direct form II, as scipy's sosfilt */
            const double y = SOS[j][0] * xc + s->zf[c][j][0];
            s->zf[c][j][0] = SOS[j][1] * xc - SOS[j][4] * y + s->zf[c][j][1];
            s->zf[c][j][1] = SOS[j][2] * xc - SOS[j][5] * y;
            xc = y;
        }}
        s->fwd[s->fnext][c] = xc;
        s->fwd[s->fnext + HALF + 1][c] = xc;
    }}
    s->fnext = (s->fnext + 1) % (HALF + 1);
}}

/* Force at the oldest instant of the forward outputs held (physical part at r). */
static double stream_point(const clm_ff_stream *s, const double *r)
{{
    const double (*w)[4] = s->fwd + s->fnext;
    clm_ff_real a0 = R(0.0), v0 = R(0.0), s0 = R(0.0), y0 = R(0.0);
    clm_ff_real a1 = R(0.0), v1 = R(0.0), s1 = R(0.0), y1 = R(0.0);
    clm_ff_real f[4];
    int i;
    for (i = 0; i + 1 <= HALF; i += 2) {{ /* two chains per feature: the additions overlap */
        const clm_ff_real g0 = BACK[i], g1 = BACK[i + 1];
        a0 += g0 * (clm_ff_real)w[i][0]; v0 += g0 * (clm_ff_real)w[i][1];
        s0 += g0 * (clm_ff_real)w[i][2]; y0 += g0 * (clm_ff_real)w[i][3];
        a1 += g1 * (clm_ff_real)w[i + 1][0]; v1 += g1 * (clm_ff_real)w[i + 1][1];
        s1 += g1 * (clm_ff_real)w[i + 1][2]; y1 += g1 * (clm_ff_real)w[i + 1][3];
    }}
    for (; i <= HALF; ++i) {{
        a0 += BACK[i] * (clm_ff_real)w[i][0]; v0 += BACK[i] * (clm_ff_real)w[i][1];
        s0 += BACK[i] * (clm_ff_real)w[i][2]; y0 += BACK[i] * (clm_ff_real)w[i][3];
    }}
    f[0] = a0 + a1; f[1] = v0 + v1; f[2] = s0 + s1; f[3] = y0 + y1;
    return (double)(physical(r) + network(f));
}}

void clm_ff_stream_init(clm_ff_stream *s, double r0)
{{
    int i, j, c;
    for (i = 0; i < 2 * CLM_FF_WINDOW; ++i)
        s->buf[i] = r0;
    s->next = 0;
    /* at rest: a = v = sign v = 0, y = r0; the sections in their steady state */
    for (c = 0; c < 4; ++c)
        for (j = 0; j < CLM_FF_NSEC; ++j) {{
            s->zf[c][j][0] = c == 3 ? SOS_ZI[j][0] * r0 : 0.0;
            s->zf[c][j][1] = c == 3 ? SOS_ZI[j][1] * r0 : 0.0;
        }}
    for (i = 0; i < 2 * (HALF + 1); ++i) {{
        s->fwd[i][0] = s->fwd[i][1] = s->fwd[i][2] = 0.0;
        s->fwd[i][3] = r0;
    }}
    s->fnext = 0;
    s->p_next = stream_point(s, &s->buf[CLM_FF_LAG + 1]);
}}

double clm_ff_stream_push(clm_ff_stream *s, double r_newest)
{{
    const double *r, *n;
    double x[4], p, u;
    s->buf[s->next] = r_newest;
    s->buf[s->next + CLM_FF_WINDOW] = r_newest;
    s->next = (s->next + 1) % CLM_FF_WINDOW;
    r = &s->buf[s->next + CLM_FF_LAG];   /* r[k] */
    n = r + CLM_FF_LAG;                  /* r[k + HALF + 1]: the newest instant with differences */
    x[1] = (n[1] - n[-1]) / (2.0 * CLM_FF_TS);
    x[0] = (n[1] - 2.0 * n[0] + n[-1]) / (CLM_FF_TS * CLM_FF_TS);
    x[2] = x[1] > 0.0 ? 1.0 : (x[1] < 0.0 ? -1.0 : 0.0);
    x[3] = n[0];
    forward(s, x);                       /* forward outputs now cover k+1 .. k+HALF+1 */
    p = stream_point(s, r + 1);          /* force at k+1 */
    u = 0.5 * (s->p_next + p);
    s->p_next = p;
    return u;
}}
"""


_RAW_FEATURES = """
/* Raw features [a, v, sign v, y] at the instant of r[0], differenced as the product does. */
static void raw_features(const double *r, clm_ff_real f[4])
{
    const double v = (r[1] - r[-1]) / (2.0 * CLM_FF_TS);
    f[0] = (clm_ff_real)((r[1] - 2.0 * r[0] + r[-1]) / (CLM_FF_TS * CLM_FF_TS));
    f[1] = (clm_ff_real)v;
    f[2] = v > 0.0 ? R(1.0) : (v < 0.0 ? R(-1.0) : R(0.0));
    f[3] = (clm_ff_real)r[0];
}

double clm_ff(const double *r)
{
    clm_ff_real f0[4], f1[4];
    raw_features(r, f0);
    raw_features(r + 1, f1);
    return (double)(R(0.5) * ((physical(r) + network(f0)) + (physical(r + 1) + network(f1))));
}
"""


def _network_source(wf: WindowFeedforward) -> str:
    m = wf.half
    h = wf.kernel
    # The filter at the instants k (column 0) and k+1 (column 1) over i = -m .. m+1.
    both = np.zeros((2 * m + 2, 2))
    both[:-1, 0] = h
    both[1:, 1] = h
    net = wf.network
    tables = [f"#define HALF {m}\n"]
    if m > 0:
        tables += [
              "static const double INV_TS2 = 1.0 / (CLM_FF_TS * CLM_FF_TS);\n"
              "static const double INV_2TS = 1.0 / (2.0 * CLM_FF_TS);\n",
              f"/* The feature filter's FIR at the instants k and k+1, over the features at "
              f"r[k-HALF .. k+HALF+1]. */\n"
              f"static const clm_ff_real KERNEL[2 * HALF + 2][2] = {_matrix(both)};\n"]
    tables += [f"static const clm_ff_real IN_MEAN[4] = {_array(net.input_mean)};\n",
               f"static const clm_ff_real IN_STD[4] = {_array(net.input_std)};\n"]
    widths = [4]
    for li, (w, b) in enumerate(net.layers):
        tables.append(f"static const clm_ff_real W{li}[{w.shape[0]}][{w.shape[1]}] = "
                      f"{_matrix(w)};\n")
        tables.append(f"static const clm_ff_real B{li}[{len(b)}] = {_array(b)};\n")
        widths.append(w.shape[0])
    tables.append(f"static const clm_ff_real OUT_W[{len(net.out_w)}] = {_array(net.out_w)};\n")
    tables.append(f"static const clm_ff_real OUT_B = {_num(net.out_b)};\n")
    layers = []
    for li in range(len(net.layers)):
        a, b = widths[li], widths[li + 1]
        layers.append(f"""\
    {{
        clm_ff_real h{li + 1}[{b}];
        int o, j;
        for (o = 0; o < {b}; ++o) {{
            clm_ff_real x = B{li}[o];
            for (j = 0; j < {a}; ++j)
                x += W{li}[o][j] * h{li}[j];
            h{li + 1}[o] = {_ACT[net.activation]};
        }}
""")
    last = len(net.layers)
    body = "".join(layers)
    closing = "    }\n" * len(net.layers)
    network = "\n" + "\n".join(tables) + f"""
/* Network force (N) of the (filtered) features f = [a, v, sign v, y]. */
static clm_ff_real network(const clm_ff_real f[4])
{{
    clm_ff_real h0[4];
    clm_ff_real out = OUT_B;
    int i;
    for (i = 0; i < 4; ++i)
        h0[i] = (f[i] - IN_MEAN[i]) / IN_STD[i];
{body}        for (i = 0; i < {widths[-1]}; ++i)
            out += OUT_W[i] * h{last}[i];
{closing}    return out;
}}
"""
    if m == 0:
        return network + _RAW_FEATURES
    return network + f"""
double clm_ff(const double *r)
{{
    /* Eight named accumulators (not an array): they stay in registers, and a compiler pairs
     * them into vector operations without reordering any sum. */
    clm_ff_real c0 = R(0.0), c1 = R(0.0), c2 = R(0.0), c3 = R(0.0);
    clm_ff_real c4 = R(0.0), c5 = R(0.0), c6 = R(0.0), c7 = R(0.0);
    clm_ff_real f0[4], f1[4];
    int i;
    for (i = 0; i < 2 * HALF + 2; ++i) {{
        /* the features at one instant, differenced in the product's order (the constant
         * factors as multiplications: within one rounding of the product's divisions) */
        const double *q = r + i - HALF;
        const double dv = q[1] - q[-1];
        const clm_ff_real a = (clm_ff_real)((q[1] - 2.0 * q[0] + q[-1]) * INV_TS2);
        const clm_ff_real v = (clm_ff_real)(dv * INV_2TS);
        /* a branch, not arithmetic: the sign of the velocity rarely changes along a window */
        const clm_ff_real s = dv > 0.0 ? R(1.0) : (dv < 0.0 ? R(-1.0) : R(0.0));
        const clm_ff_real y = (clm_ff_real)q[0];
        const clm_ff_real h0 = KERNEL[i][0], h1 = KERNEL[i][1];
        c0 += h0 * a; c1 += h1 * a; c2 += h0 * v; c3 += h1 * v;
        c4 += h0 * s; c5 += h1 * s; c6 += h0 * y; c7 += h1 * y;
    }}
    f0[0] = c0; f0[1] = c2; f0[2] = c4; f0[3] = c6;
    f1[0] = c1; f1[1] = c3; f1[2] = c5; f1[3] = c7;
    return (double)(R(0.5) * ((physical(r) + network(f0)) + (physical(r + 1) + network(f1))));
}}
"""


def write(wf: WindowFeedforward, folder) -> list:
    """Write ``clm_ff.h`` and ``clm_ff.c`` into ``folder``; returns the paths."""
    from pathlib import Path

    folder = Path(folder)
    paths = [folder / "clm_ff.h", folder / "clm_ff.c"]
    paths[0].write_text(header(wf))
    paths[1].write_text(source(wf))
    return paths
