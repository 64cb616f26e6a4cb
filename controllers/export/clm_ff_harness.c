/* Test and timing harness around an exported clm_ff (compiled beside clm_ff.c by cbuild.py).
 * Not part of an export: a target calls clm_ff or clm_ff_stream_push itself. */
#define _POSIX_C_SOURCE 199309L
#include "clm_ff.h"
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

int clm_ff_lag(void) { return CLM_FF_LAG; }
int clm_ff_lead(void) { return CLM_FF_LEAD; }

/* The harness speaks metres and newtons in double; the float build reads counts. */
#ifdef CLM_FF_FLOAT
double clm_ff_count_m(void) { return CLM_FF_COUNT_M; }
/* r (m) as counts, rounded to the nearest (halves away from 0); NaN, infinities and values
 * beyond 2^62 counts become a count beyond CLM_FF_COUNT_MAX, which the stream rejects as it
 * rejects NaN. */
static clm_ff_pos to_pos(double r)
{
    const double c = r / CLM_FF_COUNT_M;
    if (!(c > -4.6e18 && c < 4.6e18))
        return (clm_ff_pos)INT64_MAX;
    return (clm_ff_pos)llround(c);
}
#else
double clm_ff_count_m(void) { return 0.0; }
static clm_ff_pos to_pos(double r) { return r; }
#endif

/* A window of doubles as the build's positions (w: CLM_FF_WINDOW samples). */
static void window_pos(const double *w, clm_ff_pos *out)
{
    long j;
    for (j = 0; j < CLM_FF_WINDOW; ++j)
        out[j] = to_pos(w[j]);
}

/* A record of doubles as the build's positions, allocated (free it). */
static clm_ff_pos *record_pos(const double *r, long n)
{
    clm_ff_pos *p = n > 0 ? (clm_ff_pos *)malloc((size_t)n * sizeof *p) : NULL;
    long k;
    if (p)
        for (k = 0; k < n; ++k)
            p[k] = to_pos(r[k]);
    return p;
}

/* out[b] = clm_ff of row b of windows (n rows of width doubles). */
void clm_ff_windows(const double *windows, long n, long width, double *out)
{
    clm_ff_pos w[CLM_FF_WINDOW];
    long b;
    if (width != CLM_FF_WINDOW)
        return;
    for (b = 0; b < n; ++b) {
        window_pos(windows + b * width, w);
        out[b] = (double)clm_ff(w + CLM_FF_LAG);
    }
}

/* u_ff of a record r[0..n-1] through the streaming form, the record held at its ends. */
void clm_ff_record(const double *r, long n, double *out)
{
    clm_ff_stream s;
    clm_ff_pos *p = record_pos(r, n);
    long k;
    if (!p)
        return;
    clm_ff_stream_init(&s, p[0]);
    /* push r[0 .. LEAD-1]: the window then ends at r[LEAD-1]; k = -1 */
    for (k = 0; k < CLM_FF_LEAD; ++k)
        (void)clm_ff_stream_push(&s, p[k < n ? k : n - 1]);
    for (k = 0; k < n; ++k) {
        long newest = k + CLM_FF_LEAD;
        out[k] = (double)clm_ff_stream_push(&s, p[newest < n ? newest : n - 1]);
    }
    free(p);
}

/* The streaming form over a padded record rp[0 .. n+LAG+LEAD-1] (r[k] = rp[k + LAG], any value
 * allowed, NaN too), with its status: started at rest at rp[0] (k0 < 0) or from the window of
 * sample k0 (out[k0] from clm_ff_stream_start; pushed on after a rejected start too); limits
 * set after that unless max_force < 0. flags: 1, the limits set before init or start instead;
 * 2, a stream initialised at rest at rp[0] (and its limits set) before the start at k0.
 * Returns the status of init/start/limits (OR). */
unsigned clm_ff_record_status(const double *rp, long n, long k0, double max_force,
                              double max_slew, int flags, double *out, unsigned *status)
{
    clm_ff_stream s;
    clm_ff_pos *p = record_pos(rp, n + CLM_FF_LAG + CLM_FF_LEAD);
    clm_ff_real u = 0;
    unsigned st = CLM_FF_OK;
    long k, j;
    const int limits = !(max_force < 0.0); /* -1: none; NaN and 0 reach clm_ff_stream_limits */
    if (!p)
        return CLM_FF_REJECTED;
    memset(&s, 0, sizeof s);
    if (limits && (flags & 1))
        st |= clm_ff_stream_limits(&s, (clm_ff_real)max_force, (clm_ff_real)max_slew);
    if (k0 < 0 || (flags & 2)) {
        st |= clm_ff_stream_init(&s, p[0]);
        if (limits && !(flags & 1))
            st |= clm_ff_stream_limits(&s, (clm_ff_real)max_force, (clm_ff_real)max_slew);
    }
    if (k0 < 0) {
        for (j = 0; j < n + CLM_FF_LEAD; ++j) {
            const unsigned sj = clm_ff_stream_step(&s, p[CLM_FF_LAG + j], &u);
            if (j >= CLM_FF_LEAD) {
                out[j - CLM_FF_LEAD] = (double)u;
                status[j - CLM_FF_LEAD] = sj;
            }
        }
        free(p);
        return st;
    }
    st |= clm_ff_stream_start(&s, p + CLM_FF_LAG + k0, &u);
    out[k0] = (double)u;
    status[k0] = st;
    if (limits && !(flags & 3))
        st |= clm_ff_stream_limits(&s, (clm_ff_real)max_force, (clm_ff_real)max_slew);
    for (k = k0 + 1; k < n; ++k) {
        status[k] = clm_ff_stream_step(&s, p[CLM_FF_LAG + k + CLM_FF_LEAD], &u);
        out[k] = (double)u;
    }
    free(p);
    return st;
}

/* clm_ff_eval on n windows: out[b], status[b]. */
void clm_ff_eval_windows(const double *windows, long n, long width, double *out,
                         unsigned *status)
{
    clm_ff_pos w[CLM_FF_WINDOW];
    clm_ff_real u;
    long b;
    if (width != CLM_FF_WINDOW)
        return;
    for (b = 0; b < n; ++b) {
        window_pos(windows + b * width, w);
        status[b] = clm_ff_eval(w + CLM_FF_LAG, &u);
        out[b] = (double)u;
    }
}

static double now_s(void)
{
    struct timespec t;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t); /* CPU time: the machine is shared */
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

/* CPU time (ns per call) of blocks of `block` consecutive clm_ff calls over r[LAG .. n-LEAD-1],
 * repeated `repeats` times: out_ns[0 .. return-1] (at most max_blocks). Short blocks let the
 * caller see through the bursts of a shared machine (their minimum and median). */
long clm_ff_time_blocks(const double *r, long n, long repeats, long block, double *out_ns,
                        long max_blocks)
{
    volatile clm_ff_real sink = 0;
    clm_ff_pos *p = record_pos(r, n);
    long k, j, rep, count = 0;
    if (!p)
        return 0;
    for (rep = 0; rep < repeats; ++rep)
        for (k = CLM_FF_LAG; k + block + CLM_FF_LEAD < n && count < max_blocks; k += block) {
            double t0 = now_s();
            for (j = 0; j < block; ++j)
                sink += clm_ff(p + k + j);
            out_ns[count++] = 1e9 * (now_s() - t0) / (double)block;
        }
    (void)sink;
    free(p);
    return count;
}

/* The same for the streaming form: one push per sample of r (held at its ends), timed in blocks. */
long clm_ff_stream_time_blocks(const double *r, long n, long repeats, long block, double *out_ns,
                               long max_blocks)
{
    clm_ff_stream s;
    volatile clm_ff_real sink = 0;
    clm_ff_pos *p = record_pos(r, n);
    long k, j, rep, count = 0;
    if (!p)
        return 0;
    for (rep = 0; rep < repeats; ++rep) {
        clm_ff_stream_init(&s, p[0]);
        for (k = 0; k + block <= n && count < max_blocks; k += block) {
            double t0 = now_s();
            for (j = 0; j < block; ++j)
                sink += clm_ff_stream_push(&s, p[k + j]);
            out_ns[count++] = 1e9 * (now_s() - t0) / (double)block;
        }
    }
    (void)sink;
    free(p);
    return count;
}
