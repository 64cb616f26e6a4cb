
/* A usable reference sample, the one check of every call that takes samples (clm_ff_eval on
 * each sample of its window, the stream on each push, init and start): finite and within the
 * position envelope [CLM_FF_R_MIN, CLM_FF_R_MAX] m; the float build: counts within that
 * envelope and within +-CLM_FF_COUNT_MAX, so that no difference overflows. The finite test
 * reads the bits (-ffast-math cannot assume it away); & rather than &&: no branch, a loop of it
 * vectorises. */
#ifdef CLM_FF_FLOAT
static const clm_ff_pos COUNT_LO = CLM_FF_R_MIN / CLM_FF_COUNT_M <= -2.3e18
    ? -CLM_FF_COUNT_MAX : (clm_ff_pos)(CLM_FF_R_MIN / CLM_FF_COUNT_M);
static const clm_ff_pos COUNT_HI = CLM_FF_R_MAX / CLM_FF_COUNT_M >= 2.3e18
    ? CLM_FF_COUNT_MAX : (clm_ff_pos)(CLM_FF_R_MAX / CLM_FF_COUNT_M);
static CLM_FF_INLINE int sample_ok(clm_ff_pos r)
{
    return (r >= COUNT_LO) & (r <= COUNT_HI);
}
#else
static CLM_FF_INLINE int sample_ok(clm_ff_pos r)
{
    return is_finite_bits(r) & (r >= CLM_FF_R_MIN) & (r <= CLM_FF_R_MAX);
}
#endif

/* Every sample of the window r[-LAG .. LEAD] is usable: sample_ok of each. For a long window
 * the double build first takes the window's sums, least and largest values, four independent chains so that the
 * additions overlap: finite sums mean no NaN or infinity, and then the extremes decide; only a
 * window that fails that (or whose sum overflowed) is checked sample by sample, so the answer is
 * sample_ok's. */
static int window_ok(const clm_ff_pos *r)
{
    int i, ok = 1;
#if !defined(CLM_FF_FLOAT) && CLM_FF_WINDOW > 16 /* a LIP's 4 samples: the plain loop */
    const clm_ff_pos *w = r - CLM_FF_LAG;
    clm_ff_pos s[4] = {0, 0, 0, 0}, lo[4], hi[4];
    int j;
    for (j = 0; j < 4; ++j)
        lo[j] = hi[j] = w[0];
    for (i = 0; i + 4 <= CLM_FF_WINDOW; i += 4)
        for (j = 0; j < 4; ++j) {
            s[j] += w[i + j];
            lo[j] = w[i + j] < lo[j] ? w[i + j] : lo[j];
            hi[j] = w[i + j] > hi[j] ? w[i + j] : hi[j];
        }
    for (; i < CLM_FF_WINDOW; ++i) {
        s[0] += w[i];
        lo[0] = w[i] < lo[0] ? w[i] : lo[0];
        hi[0] = w[i] > hi[0] ? w[i] : hi[0];
    }
    for (j = 1; j < 4; ++j) {
        lo[0] = lo[j] < lo[0] ? lo[j] : lo[0];
        hi[0] = hi[j] > hi[0] ? hi[j] : hi[0];
    }
    if (is_finite_bits((s[0] + s[1]) + (s[2] + s[3])) && lo[0] >= CLM_FF_R_MIN
        && hi[0] <= CLM_FF_R_MAX)
        return 1;
#endif
    for (i = -CLM_FF_LAG; i <= CLM_FF_LEAD; ++i)
        ok &= sample_ok(r[i]);
    return ok;
}

/* The force clamped to +-max_force, with its status bit. */
static clm_ff_real clamp(clm_ff_real u, clm_ff_real max_force, unsigned *st)
{
    if (u > max_force) {
        *st |= CLM_FF_CLAMPED;
        return max_force;
    }
    if (u < -max_force) {
        *st |= CLM_FF_CLAMPED;
        return -max_force;
    }
    return u;
}

clm_ff_real clm_ff(const clm_ff_pos *r)
{
    unsigned st = CLM_FF_OK;
    return window_force(r, &st);
}

unsigned clm_ff_eval(const clm_ff_pos *r, clm_ff_real *u_ff)
{
    unsigned st = CLM_FF_OK;
    clm_ff_real u;
    if (!window_ok(r)) {
        *u_ff = R(0.0);
        return CLM_FF_REJECTED;
    }
    u = window_force(r, &st);
    if (!is_finite_bits(u)) {
        *u_ff = R(0.0);
        return CLM_FF_REJECTED;
    }
    *u_ff = clamp(u, (clm_ff_real)CLM_FF_MAX_FORCE, &st);
    return st;
}

/* A check word of the limits a stream holds: init and start keep limits whose word matches
 * (set by clm_ff_stream_limits on this stream); a stream never given limits (or not yet
 * initialised) gets the export's. */
static unsigned long limits_key(const clm_ff_stream *s)
{
    unsigned char b[2 * sizeof(clm_ff_real)];
    unsigned long k = 0x2545f491UL;
    size_t i;
    memcpy(b, &s->max_force, sizeof s->max_force);
    memcpy(b + sizeof(clm_ff_real), &s->max_step, sizeof s->max_step);
    for (i = 0; i < sizeof b; ++i)
        k = (k * 31UL + b[i]) & 0xffffffffUL;
    return k | 1UL; /* never 0: a zeroed stream does not match */
}

/* The limits kept if set on this stream, else the export's. */
static void keep_limits(clm_ff_stream *s)
{
    if (s->limits_key != limits_key(s) || !(s->max_force > R(0.0) && s->max_step > R(0.0))) {
        s->max_force = (clm_ff_real)CLM_FF_MAX_FORCE;
        s->max_step = (clm_ff_real)(CLM_FF_MAX_SLEW * CLM_FF_TS);
        s->limits_key = 0UL;
    }
}

unsigned clm_ff_stream_limits(clm_ff_stream *s, clm_ff_real max_force, clm_ff_real max_slew)
{
    if (!(max_force > R(0.0) && max_slew > R(0.0))) /* NaN fails too */
        return CLM_FF_REJECTED;
    s->max_force = max_force;
    s->max_step = max_slew * (clm_ff_real)CLM_FF_TS;
    s->limits_key = limits_key(s);
    return CLM_FF_OK;
}

/* A rejected init or start: the stream says so on every push (0 N, REJECTED | STOPPED) until
 * a good init or start. */
static unsigned stop(clm_ff_stream *s)
{
    keep_limits(s);
    s->stopped = 1;
    s->degraded = 0;
    s->u_last = R(0.0);
    s->status = CLM_FF_REJECTED | CLM_FF_STOPPED;
    return s->status;
}

/* Init's buffer: every sample r0 (usable). */
static void fill_at_rest(clm_ff_stream *s, clm_ff_pos r0)
{
    int i;
    for (i = 0; i < 2 * CLM_FF_WINDOW; ++i)
        s->buf[i] = r0;
    s->next = 0;
}

/* Start's buffer: the window r[-LAG..LEAD] (usable). */
static void fill_window(clm_ff_stream *s, const clm_ff_pos *r)
{
    int i;
    for (i = 0; i < CLM_FF_WINDOW; ++i)
        s->buf[i] = s->buf[i + CLM_FF_WINDOW] = r[i - CLM_FF_LAG];
    s->next = 0;
}

/* The state after a good init or start: the force last returned, the limits kept. */
static void reset(clm_ff_stream *s, clm_ff_real u)
{
    keep_limits(s);
    s->stopped = 0;
    s->degraded = 0;
    s->u_last = u;
    s->status = CLM_FF_OK;
}

/* The sample put in place of a rejected one: the three newest continued at constant
 * acceleration (a machine at rest stays where it is, bit for bit; a move goes on as it went),
 * or the newest itself where that continuation is not a usable sample. */
static clm_ff_pos extrapolated(const clm_ff_stream *s)
{
    const clm_ff_pos *b = &s->buf[s->next + CLM_FF_WINDOW]; /* b[-1]: the newest */
    const clm_ff_pos d1 = b[-1] - b[-2], d2 = b[-2] - b[-3];
    clm_ff_pos x;
#ifdef CLM_FF_FLOAT
    const clm_ff_pos big = (clm_ff_pos)1 << 59; /* so that the sum below cannot overflow */
    if (d1 > big || d1 < -big || d2 > big || d2 < -big)
        return b[-1];
#endif
    x = b[-1] + (d1 + (d1 - d2));
    return sample_ok(x) ? x : b[-1];
}

/* The newest sample, or its extrapolation in place of a rejected one; *st: the status so far. */
static CLM_FF_INLINE clm_ff_pos accept(clm_ff_stream *s, clm_ff_pos r_newest, unsigned *st)
{
    *st = CLM_FF_OK;
    if (!sample_ok(r_newest)) {
        r_newest = extrapolated(s);
        *st = CLM_FF_REJECTED;
        s->degraded = CLM_FF_WINDOW;
    }
    if (s->degraded > 0) {
        *st |= CLM_FF_DEGRADED;
        --s->degraded;
    }
    return r_newest;
}

/* The limits on the force u (N) of a push (skipped where none is set: no chain of calls through
 * u_last then), its output and status. */
static CLM_FF_INLINE unsigned finish(clm_ff_stream *s, clm_ff_real u, unsigned st,
                                     clm_ff_real *u_ff)
{
    if (s->max_step < RHUGE || s->max_force < RHUGE) {
        if (u > s->u_last + s->max_step) {
            u = s->u_last + s->max_step;
            st |= CLM_FF_SLEWED;
        } else if (u < s->u_last - s->max_step) {
            u = s->u_last - s->max_step;
            st |= CLM_FF_SLEWED;
        }
        u = clamp(u, s->max_force, &st);
    }
    s->u_last = u;
    s->status = st;
    *u_ff = u;
    return st;
}
