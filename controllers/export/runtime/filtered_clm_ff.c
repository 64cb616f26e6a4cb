
/* The held force (N) of the window at r[0]; *st gets the envelope's status. */
static clm_ff_real window_force(const clm_ff_pos *r, unsigned *st)
{
    clm_ff_real f0[4], f1[4];
#ifdef CLM_FF_AVX2
    if (CLM_FF_HAS_AVX2()) {
        double net[2];
        filtered_features_avx2(r, f0, f1);
        clip_features(f0, st);
        clip_features(f1, st);
        if (!features_finite(f0, f1))
            return (double)NAN;
        NETWORK2_AVX2(f0, f1, net);
        return 0.5 * ((physical(f0) + net[0]) + (physical(f1) + net[1]));
    }
#endif
    filtered_features(r, f0, f1);
    clip_features(f0, st);
    clip_features(f1, st);
    if (!features_finite(f0, f1))
        return (clm_ff_real)NAN;
    return R(0.5) * ((physical(f0) + network(f0)) + (physical(f1) + network(f1)));
}
