/* Test and timing harness around an exported clm_ff (compiled beside clm_ff.c by cbuild.py).
 * Not part of an export: a target calls clm_ff or clm_ff_stream_push itself. */
#define _POSIX_C_SOURCE 199309L
#include "clm_ff.h"
#include <time.h>

int clm_ff_lag(void) { return CLM_FF_LAG; }
int clm_ff_lead(void) { return CLM_FF_LEAD; }

/* out[b] = clm_ff of row b of windows (n rows of width doubles). */
void clm_ff_windows(const double *windows, long n, long width, double *out)
{
    long b;
    if (width != CLM_FF_WINDOW)
        return;
    for (b = 0; b < n; ++b)
        out[b] = clm_ff(windows + b * width + CLM_FF_LAG);
}

/* u_ff of a record r[0..n-1] through the streaming form, the record held at its ends. */
void clm_ff_record(const double *r, long n, double *out)
{
    clm_ff_stream s;
    long k;
    clm_ff_stream_init(&s, r[0]);
    /* push r[0 .. LEAD-1]: the window then ends at r[LEAD-1]; k = -1 */
    for (k = 0; k < CLM_FF_LEAD; ++k)
        (void)clm_ff_stream_push(&s, r[k < n ? k : n - 1]);
    for (k = 0; k < n; ++k) {
        long newest = k + CLM_FF_LEAD;
        out[k] = clm_ff_stream_push(&s, r[newest < n ? newest : n - 1]);
    }
}

/* The streaming form over a padded record rp[0 .. n+LAG+LEAD-1] (r[k] = rp[k + LAG], any value
 * allowed, NaN too), with its status: started at rest at rp[0] (k0 < 0) or from the window of
 * sample k0 (out[k0] from clm_ff_stream_start); limits set after that unless max_force < 0.
 * Returns the status of init/start/limits (OR). */
unsigned clm_ff_record_status(const double *rp, long n, long k0, double max_force,
                              double max_slew, double *out, unsigned *status)
{
    clm_ff_stream s;
    unsigned st;
    long k, j;
    if (k0 < 0) {
        st = clm_ff_stream_init(&s, rp[0]);
        if (!(max_force < 0.0)) /* -1: none; NaN and 0 reach clm_ff_stream_limits */
            st |= clm_ff_stream_limits(&s, max_force, max_slew);
        for (j = 0; j < n + CLM_FF_LEAD; ++j) {
            double u;
            const unsigned sj = clm_ff_stream_step(&s, rp[CLM_FF_LAG + j], &u);
            if (j >= CLM_FF_LEAD) {
                out[j - CLM_FF_LEAD] = u;
                status[j - CLM_FF_LEAD] = sj;
            }
        }
        return st;
    }
    st = clm_ff_stream_start(&s, rp + CLM_FF_LAG + k0, &out[k0]);
    status[k0] = st;
    if (st != CLM_FF_OK)
        return st; /* refused: the stream was not filled */
    if (!(max_force < 0.0))
        st |= clm_ff_stream_limits(&s, max_force, max_slew);
    for (k = k0 + 1; k < n; ++k)
        status[k] = clm_ff_stream_step(&s, rp[CLM_FF_LAG + k + CLM_FF_LEAD], &out[k]);
    return st;
}

/* clm_ff_eval on n windows: out[b], status[b]. */
void clm_ff_eval_windows(const double *windows, long n, long width, double *out,
                         unsigned *status)
{
    long b;
    if (width != CLM_FF_WINDOW)
        return;
    for (b = 0; b < n; ++b)
        status[b] = clm_ff_eval(windows + b * width + CLM_FF_LAG, &out[b]);
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
    volatile double sink = 0.0;
    long k, j, rep, count = 0;
    for (rep = 0; rep < repeats; ++rep)
        for (k = CLM_FF_LAG; k + block + CLM_FF_LEAD < n && count < max_blocks; k += block) {
            double t0 = now_s();
            for (j = 0; j < block; ++j)
                sink += clm_ff(r + k + j);
            out_ns[count++] = 1e9 * (now_s() - t0) / (double)block;
        }
    (void)sink;
    return count;
}

/* The same for the streaming form: one push per sample of r (held at its ends), timed in blocks. */
long clm_ff_stream_time_blocks(const double *r, long n, long repeats, long block, double *out_ns,
                               long max_blocks)
{
    clm_ff_stream s;
    volatile double sink = 0.0;
    long k, j, rep, count = 0;
    for (rep = 0; rep < repeats; ++rep) {
        clm_ff_stream_init(&s, r[0]);
        for (k = 0; k + block <= n && count < max_blocks; k += block) {
            double t0 = now_s();
            for (j = 0; j < block; ++j)
                sink += clm_ff_stream_push(&s, r[k + j]);
            out_ns[count++] = 1e9 * (now_s() - t0) / (double)block;
        }
    }
    (void)sink;
    return count;
}
