
/* Filtered features [a, v, sign v, y] at the instants k (f0) and k+1 (f1); portable C. */
static void filtered_features(const clm_ff_pos *r, clm_ff_real f0[4], clm_ff_real f1[4])
{
    clm_ff_real a0 = R(0.0), a1 = R(0.0), v0 = R(0.0), v1 = R(0.0);
    clm_ff_real s0 = R(0.0), s1 = R(0.0), y0 = R(0.0), y1 = R(0.0);
    int i;
    for (i = 0; i < 2 * HALF + 2; ++i) {
        const clm_ff_pos *q = r + i - HALF;
        const clm_ff_pos dv = D1(q);                                  /* 2 ts v */
        const clm_ff_real da = (clm_ff_real)D2(q);                    /* ts^2 a */
        const clm_ff_real dvr = (clm_ff_real)dv;
        const clm_ff_real s = dv > 0 ? R(1.0) : (dv < 0 ? R(-1.0) : R(0.0));
        const clm_ff_real y = (clm_ff_real)POS(q[0]);
        const clm_ff_real w0 = KERNEL[i + 1], w1 = KERNEL[i];
        a0 += w0 * da; a1 += w1 * da; v0 += w0 * dvr; v1 += w1 * dvr;
        s0 += w0 * s; s1 += w1 * s; y0 += w0 * y; y1 += w1 * y;
    }
    f0[0] = a0 * INV_TS2; f0[1] = v0 * INV_2TS; f0[2] = s0; f0[3] = y0;
    f1[0] = a1 * INV_TS2; f1[1] = v1 * INV_2TS; f1[2] = s1; f1[3] = y1;
}
