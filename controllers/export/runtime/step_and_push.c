
unsigned clm_ff_stream_step(clm_ff_stream *s, clm_ff_pos r_newest, clm_ff_real *u_ff)
{
    unsigned st;
    clm_ff_real u;
    if (s->stopped) {
        *u_ff = R(0.0);
        return s->status;
    }
    u = advance(s, r_newest, &st);
    return finish(s, u, st, u_ff);
}

clm_ff_real clm_ff_stream_push(clm_ff_stream *s, clm_ff_pos r_newest)
{
    unsigned st;
    clm_ff_real u;
    if (s->stopped)
        return R(0.0);
    u = advance(s, r_newest, &st);
    (void)finish(s, u, st, &u);
    return u;
}
