
unsigned clm_ff_stream_init(clm_ff_stream *s, clm_ff_pos r0)
{
    unsigned st = CLM_FF_OK;
    if (!sample_ok(r0))
        return stop(s);
    fill_at_rest(s, r0);
    reset(s, window_force(&s->buf[CLM_FF_LAG], &st));
    return CLM_FF_OK;
}

unsigned clm_ff_stream_start(clm_ff_stream *s, const clm_ff_pos *r, clm_ff_real *u_ff)
{
    unsigned st = CLM_FF_OK;
    if (!window_ok(r))
        return stop(s);
    fill_window(s, r);
    *u_ff = window_force(r, &st);
    reset(s, *u_ff);
    return st;
}

/* One push before the limits: the force (N) and *st. */
static CLM_FF_INLINE clm_ff_real advance(clm_ff_stream *s, clm_ff_pos r_newest, unsigned *st)
{
    r_newest = accept(s, r_newest, st);
    s->buf[s->next] = r_newest;
    s->buf[s->next + CLM_FF_WINDOW] = r_newest;
    s->next = (s->next + 1) % CLM_FF_WINDOW;
    /* The oldest sample is at buf[next]; r[k] is CLM_FF_LAG after it. */
    return window_force(&s->buf[s->next + CLM_FF_LAG], st);
}
