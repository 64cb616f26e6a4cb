
unsigned clm_ff_stream_init(clm_ff_stream *s, clm_ff_pos r0)
{
    unsigned st = CLM_FF_OK;
    int i;
    if (!in_range(r0)) {
        r0 = 0;
        st = CLM_FF_REJECTED;
    }
    for (i = 0; i < 2 * CLM_FF_WINDOW; ++i)
        s->buf[i] = r0;
    s->next = 0;
    reset(s, r0, clm_ff(&s->buf[CLM_FF_LAG]));
    s->status = st;
    return st;
}

unsigned clm_ff_stream_start(clm_ff_stream *s, const clm_ff_pos *r, clm_ff_real *u_ff)
{
    int i;
    for (i = -CLM_FF_LAG; i <= CLM_FF_LEAD; ++i)
        if (!in_range(r[i]))
            return CLM_FF_REJECTED;
    for (i = 0; i < CLM_FF_WINDOW; ++i)
        s->buf[i] = s->buf[i + CLM_FF_WINDOW] = r[i - CLM_FF_LAG];
    s->next = 0;
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
