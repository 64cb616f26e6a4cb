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
