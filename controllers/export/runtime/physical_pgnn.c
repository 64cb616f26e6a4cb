/* Physical layer (N) of the features f = [a, v, sign v, y] the network sees. */
static clm_ff_real physical(const clm_ff_real f[4])
{
    return ${rigid_body};
}

/* The features of both instants are finite (a NaN or an infinity in the window reaches them:
 * every instant has a non-zero weight). */
static int features_finite(const clm_ff_real f0[4], const clm_ff_real f1[4])
{
    return is_finite_bits(f0[0] + f0[1] + f0[2] + f0[3] + f1[0] + f1[1] + f1[2] + f1[3]);
}

/* The features' acceleration and velocity cut to the envelope (+-CLM_FF_A_MAX m/s^2,
 * +-CLM_FF_V_MAX m/s); *st gets CLM_FF_CLAMPED where one was. Inside it, no change. */
static CLM_FF_INLINE void clip_features(clm_ff_real f[4], unsigned *st)
{
    f[0] = clip(f[0], (clm_ff_real)CLM_FF_A_MAX, st);
    f[1] = clip(f[1], (clm_ff_real)CLM_FF_V_MAX, st);
}
