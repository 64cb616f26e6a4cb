
/* A stream sample it can use: finite and within +-CLM_FF_R_MAX m (float build: counts within
 * +-CLM_FF_COUNT_MAX, so that no difference overflows). */
static int in_range(clm_ff_pos r)
{
#ifdef CLM_FF_FLOAT
    return r >= -CLM_FF_COUNT_MAX && r <= CLM_FF_COUNT_MAX;
#elif DBL_MANT_DIG == 53 && DBL_MAX_EXP == 1024
    /* |r| <= R_MAX as integers: positive doubles order as their bits, and NaN and inf lie
     * above every finite value (one compare, and -ffast-math cannot drop it) */
    const double limit = CLM_FF_R_MAX;
    unsigned long long b, m;
    memcpy(&b, &r, sizeof b);
    memcpy(&m, &limit, sizeof m);
    return (b & 0x7fffffffffffffffULL) <= m;
#else
    return is_finite_bits(r) && r >= -CLM_FF_R_MAX && r <= CLM_FF_R_MAX;
#endif
}

/* The force (N) clamped to +-max_force, with its status bit. */
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

unsigned clm_ff_eval(const clm_ff_pos *r, clm_ff_real *u_ff)
{
    unsigned st = CLM_FF_OK;
    const clm_ff_real u = clm_ff(r);
    if (!is_finite_bits(u)) {
        *u_ff = R(0.0);
        return CLM_FF_REJECTED;
    }
    *u_ff = clamp(u, (clm_ff_real)CLM_FF_MAX_FORCE, &st);
    return st;
}

/* Init's buffer: every sample r0 (0 when r0 is unusable, with CLM_FF_REJECTED); returns the
 * status and the sample it filled with. */
static unsigned fill_at_rest(clm_ff_stream *s, clm_ff_pos *r0)
{
    unsigned st = CLM_FF_OK;
    int i;
    if (!in_range(*r0)) {
        *r0 = 0;
        st = CLM_FF_REJECTED;
    }
    for (i = 0; i < 2 * CLM_FF_WINDOW; ++i)
        s->buf[i] = *r0;
    s->next = 0;
    return st;
}

/* Start's buffer: the window r[-LAG..LEAD] if every sample is usable (1), else nothing (0). */
static int fill_window(clm_ff_stream *s, const clm_ff_pos *r)
{
    int i;
    for (i = -CLM_FF_LAG; i <= CLM_FF_LEAD; ++i)
        if (!in_range(r[i]))
            return 0;
    for (i = 0; i < CLM_FF_WINDOW; ++i)
        s->buf[i] = s->buf[i + CLM_FF_WINDOW] = r[i - CLM_FF_LAG];
    s->next = 0;
    return 1;
}

/* The state after init or start: the newest sample, the force last returned, export limits. */
static void reset(clm_ff_stream *s, clm_ff_pos last_good, clm_ff_real u)
{
    s->last_good = last_good;
    s->degraded = 0;
    s->max_force = (clm_ff_real)CLM_FF_MAX_FORCE;
    s->max_step = (clm_ff_real)(CLM_FF_MAX_SLEW * CLM_FF_TS);
    s->u_last = u;
    s->status = CLM_FF_OK;
}

unsigned clm_ff_stream_limits(clm_ff_stream *s, clm_ff_real max_force, clm_ff_real max_slew)
{
    if (!(max_force > R(0.0) && max_slew > R(0.0))) /* NaN fails too */
        return CLM_FF_REJECTED;
    s->max_force = max_force;
    s->max_step = max_slew * (clm_ff_real)CLM_FF_TS;
    return CLM_FF_OK;
}

/* The newest sample, or the last good one in place of a rejected one; *st: the status so far. */
static CLM_FF_INLINE clm_ff_pos accept(clm_ff_stream *s, clm_ff_pos r_newest, unsigned *st)
{
    *st = CLM_FF_OK;
    if (in_range(r_newest)) {
        s->last_good = r_newest;
    } else {
        r_newest = s->last_good;
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
