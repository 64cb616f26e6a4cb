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
 * k+1 for the next call, about half the work of clm_ff. Once the window has been filled
 * (clm_ff_stream_init at rest, clm_ff_stream_start from a window),
 * ${exact}.
 *
 * Bad input. clm_ff returns NaN (both builds) for a window holding a NaN or an infinity;
 * clm_ff_eval returns CLM_FF_REJECTED and 0 N for a window holding a sample that is not usable
 * (not finite, or outside [CLM_FF_R_MIN, CLM_FF_R_MAX] m: the same check as the stream's). The
 * stream puts the three newest samples continued at constant acceleration in place of such a
 * sample and reports CLM_FF_REJECTED, then CLM_FF_DEGRADED until that sample has left the window
 * (CLM_FF_WINDOW pushes); after that its force is the exact one again (to the export's
 * tolerance: the filter's recursion forgets the sample as its impulse response decays). A
 * rejected init or start stops the stream: every push returns 0 N and
 * CLM_FF_REJECTED | CLM_FF_STOPPED until a good init or start.
 *
 * Limits. clm_ff_eval and the stream clamp the force to +-CLM_FF_MAX_FORCE (N); the stream
 * also limits its rate of change to CLM_FF_MAX_SLEW (N/s); both from the export, changeable
 * per stream at run time (clm_ff_stream_limits; init and start keep what it set). The velocity
 * and acceleration the model reads are cut to the envelope (CLM_FF_V_MAX, CLM_FF_A_MAX) in
 * every call. Inside the limits and the envelope nothing is changed. Every status word is 0
 * (CLM_FF_OK) or an OR of the CLM_FF_* bits below.
 *
 * Model:
${model}
 * Export:
${trace}
 *
 * Compile: C99, link -lm. With GCC or Clang on x86-64 a PGNN's clm_ff.c also holds an AVX2 and
 * FMA path (intrinsics, target attributes), taken per call where the CPU has both: no flag
 * needed, and the same results to rounding; -DCLM_FF_PORTABLE leaves it out. -DCLM_FF_FLOAT
 * is for an FPU without double: the reference as int64 counts of CLM_FF_COUNT_M m, all
 * arithmetic in float (against the double build on the same counts, measured 1e-7 of the peak
 * force for a LIP, 6e-7 for clm_ff and 3e-6 for the stream of an n_l = 16 PGNN; docs/export.md
 * also gives what the rounding to counts costs). The maths
 * functions are macros (CLM_FF_EXP, CLM_FF_SIN, CLM_FF_POW, CLM_FF_FABS, CLM_FF_LOG1P,
 * CLM_FF_ERF, CLM_FF_SQRT) a -D can replace (TcMath, CMSIS).
 */
#ifndef CLM_FF_H
#define CLM_FF_H

#define CLM_FF_TS ${ts} /* s: sample time */
#define CLM_FF_LAG ${lag} /* samples before k read */
#define CLM_FF_LEAD ${lead} /* samples after k read */
#define CLM_FF_WINDOW (CLM_FF_LAG + 1 + CLM_FF_LEAD)
#define CLM_FF_HALF ${half} /* half-length of the network's feature filter (0: none) */
#define CLM_FF_NSEC ${nsec} /* second-order sections of that filter (state of the stream) */
#ifndef CLM_FF_MAX_FORCE
#define CLM_FF_MAX_FORCE ${max_force} /* N: |force| limit, as exported (a -D overrides it) */
#endif
#ifndef CLM_FF_MAX_SLEW
#define CLM_FF_MAX_SLEW ${max_slew} /* N/s: the stream's rate limit, as exported (a -D overrides it) */
#endif
/* The envelope: a reference sample outside [CLM_FF_R_MIN, CLM_FF_R_MAX] m is rejected as a
 * NaN is; the velocity and acceleration the model reads are cut to +-CLM_FF_V_MAX m/s and
 * +-CLM_FF_A_MAX m/s^2 (CLM_FF_CLAMPED). As exported (${envelope}); a -D overrides each. */
#ifndef CLM_FF_R_MIN
#define CLM_FF_R_MIN ${r_min}
#endif
#ifndef CLM_FF_R_MAX
#define CLM_FF_R_MAX ${r_max}
#endif
#ifndef CLM_FF_V_MAX
#define CLM_FF_V_MAX ${v_max}
#endif
#ifndef CLM_FF_A_MAX
#define CLM_FF_A_MAX ${a_max}
#endif

/* The build's types. Default: the reference in m (double), forces in N (double). With
 * -DCLM_FF_FLOAT (an FPU without double precision): the reference as a fixed-point position,
 * integer counts of CLM_FF_COUNT_M m (int64_t: differences exact, no cancellation), forces and
 * all arithmetic in float; no double is computed anywhere (docs/export.md states the error). */
#define CLM_FF_COUNT_M ${count_m} /* m per count of the float build (export --count-m) */
#define CLM_FF_COUNT_MAX 2305843009213693951LL /* |counts| accepted: 2^61 - 1, no difference overflows */
#ifdef CLM_FF_FLOAT
#include <stdint.h>
typedef int64_t clm_ff_pos; /* reference sample: a fixed-point position, counts of CLM_FF_COUNT_M m */
typedef float clm_ff_real;  /* force (N) and arithmetic */
#else
typedef double clm_ff_pos;  /* reference sample, m */
typedef double clm_ff_real; /* force (N) and arithmetic */
#endif

/* Status bits (0: CLM_FF_OK, the exact force of the product). */
#define CLM_FF_OK 0u
#define CLM_FF_REJECTED 1u /* this input was not usable (not finite, outside the envelope) */
#define CLM_FF_DEGRADED 2u /* the window holds a held sample in place of a rejected one */
#define CLM_FF_CLAMPED 4u  /* the force was limited to +-max_force, or the envelope cut v or a */
#define CLM_FF_SLEWED 8u   /* the force's change was limited to max_slew */
#define CLM_FF_STOPPED 16u /* a rejected init or start: 0 N until a good one */

#ifdef __cplusplus
extern "C" {
#endif

/* Force (N) to hold over sample k; r points at r[k] (m), r[-CLM_FF_LAG..CLM_FF_LEAD] valid.
 * NaN where the window holds a NaN or an infinity. */
clm_ff_real clm_ff(const clm_ff_pos *r);

/* clm_ff with a status: *u_ff the force clamped to +-CLM_FF_MAX_FORCE (N), 0 if rejected. */
unsigned clm_ff_eval(const clm_ff_pos *r, clm_ff_real *u_ff);

/* Streaming form: state of the caller (one per axis); no allocation. */
typedef struct {
    clm_ff_pos buf[2 * CLM_FF_WINDOW]; /* each sample twice: the window is always contiguous */
    int next;                      /* where the next sample goes, 0 .. CLM_FF_WINDOW-1 */
    /* PGNN: the forward half of the feature filter run recursively (exact), its last
     * CLM_FF_HALF + 1 outputs (twice, contiguous), and the force at the next instant. */
    clm_ff_real zf[4][CLM_FF_NSEC][2];
    clm_ff_real fwd[4][2 * (CLM_FF_HALF + 1)];
    int fnext;
    clm_ff_real p_next;
    int degraded;           /* pushes until an extrapolated sample has left the window */
    int stopped;            /* a rejected init or start: no window */
    clm_ff_real max_force;  /* N */
    clm_ff_real max_step;   /* N per sample: max_slew * CLM_FF_TS */
    clm_ff_real u_last;     /* N: the force returned last */
    unsigned long limits_key; /* check word of limits set by clm_ff_stream_limits */
    unsigned status;    /* of the last call */
} clm_ff_stream;

/* Fill the window with the rest position r0 (m): the machine at rest before the motion; the
 * limits set on this stream by clm_ff_stream_limits, else the export's. A sample that is not
 * usable stops the stream (CLM_FF_REJECTED | CLM_FF_STOPPED, on every push until a good init
 * or start). */
unsigned clm_ff_stream_init(clm_ff_stream *s, clm_ff_pos r0);

/* Start on a moving reference: r points at r[k] (m), r[-CLM_FF_LAG..CLM_FF_LEAD] valid; the
 * next push takes r[k+1+CLM_FF_LEAD] and returns u_ff[k+1]. *u_ff: u_ff[k] (N, not clamped;
 * the slew limit starts from it); limits kept as by init. A window holding a sample that is
 * not usable stops the stream, as init does (*u_ff untouched). */
unsigned clm_ff_stream_start(clm_ff_stream *s, const clm_ff_pos *r, clm_ff_real *u_ff);

/* Set the limits (N, N/s; HUGE_VAL: none), kept by later inits and starts of this stream (may
 * come before the first init). CLM_FF_REJECTED (unchanged) unless both > 0. */
unsigned clm_ff_stream_limits(clm_ff_stream *s, clm_ff_real max_force, clm_ff_real max_slew);

/* Push the newest reference sample r[k + CLM_FF_LEAD] (m); *u_ff = u_ff[k] (N); the status. */
unsigned clm_ff_stream_step(clm_ff_stream *s, clm_ff_pos r_newest, clm_ff_real *u_ff);

/* clm_ff_stream_step returning the force (the status stays in s->status). */
clm_ff_real clm_ff_stream_push(clm_ff_stream *s, clm_ff_pos r_newest);

/* Known-answer self-test (clm_ff_selftest.c, vectors in clm_ff_kat.csv): 0 if the compiled code
 * gives the product's forces on the vectors' motion, else 1 + the first failing sample. No force
 * or slew limit acts on it (its motion lies inside the envelope). scratch: a stream the test
 * overwrites (afterwards its limits are the export's: init it, set yours again). */
int clm_ff_selftest(clm_ff_stream *scratch);

#ifdef __cplusplus
}
#endif
#endif /* CLM_FF_H */
