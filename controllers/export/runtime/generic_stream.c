
unsigned clm_ff_stream_init(clm_ff_stream *s, clm_ff_pos r0)
{
    const unsigned st = fill_at_rest(s, &r0);
    reset(s, r0, clm_ff(&s->buf[CLM_FF_LAG]));
    s->status = st;
    return st;
}

unsigned clm_ff_stream_start(clm_ff_stream *s, const clm_ff_pos *r, clm_ff_real *u_ff)
{
    if (!fill_window(s, r))
        return CLM_FF_REJECTED;
    *u_ff = clm_ff(r);
    reset(s, r[CLM_FF_LEAD], *u_ff);
    return CLM_FF_OK;
}

/* One push before the limits: the force (N) and *st. */
static CLM_FF_INLINE clm_ff_real advance(clm_ff_stream *s, clm_ff_pos r_newest, unsigned *st)
{
    r_newest = accept(s, r_newest, st);
    s->buf[s->next] = r_newest;
    s->buf[s->next + CLM_FF_WINDOW] = r_newest;
    s->next = (s->next + 1) % CLM_FF_WINDOW;
    /* The oldest sample is at buf[next]; r[k] is CLM_FF_LAG after it. */
    return clm_ff(&s->buf[s->next + CLM_FF_LAG]);
}
