
/* Raw features [a, v, sign v, y] at the instant of r[0], differenced as the product does. */
static void raw_features(const clm_ff_pos *r, clm_ff_real f[4])
{
    const clm_ff_real v = (clm_ff_real)VEL(r);
    f[0] = (clm_ff_real)ACC(r);
    f[1] = v;
    f[2] = v > R(0.0) ? R(1.0) : (v < R(0.0) ? R(-1.0) : R(0.0));
    f[3] = (clm_ff_real)POS(r[0]);
}

/* The held force (N) of the window at r[0]; *st gets the envelope's status. */
static clm_ff_real window_force(const clm_ff_pos *r, unsigned *st)
{
    clm_ff_real f0[4], f1[4];
    raw_features(r, f0);
    raw_features(r + 1, f1);
    clip_features(f0, st);
    clip_features(f1, st);
    if (!features_finite(f0, f1))
        return (clm_ff_real)NAN;
    return R(0.5) * ((physical(f0) + network(f0)) + (physical(f1) + network(f1)));
}
