
#ifdef CLM_FF_AVX2
/* filtered_features with AVX2 and FMA: four instants at a time. */
__attribute__((target("avx2,fma")))
static void filtered_features_avx2(const double *r, double f0[4], double f1[4])
{
    const __m256d sign_bit = _mm256_set1_pd(-0.0), one = _mm256_set1_pd(1.0);
    const __m256d zero = _mm256_setzero_pd();
    __m256d a0 = zero, a1 = zero, v0 = zero, v1 = zero, s0 = zero, s1 = zero, y0 = zero;
    __m256d y1 = zero;
    double lane[8][4], sum[8];
    int i, j;
    for (i = 0; i + 4 <= 2 * HALF + 2; i += 4) {
        const double *q = r + i - HALF;
        const __m256d y = _mm256_loadu_pd(q);
        const __m256d up = _mm256_loadu_pd(q + 1), down = _mm256_loadu_pd(q - 1);
        const __m256d dv = _mm256_sub_pd(up, down);
        const __m256d da = _mm256_add_pd(_mm256_sub_pd(up, _mm256_add_pd(y, y)), down);
        /* sign of dv: 1 with dv's sign bit, then 0 where dv == 0 */
        const __m256d s = _mm256_and_pd(_mm256_or_pd(_mm256_and_pd(dv, sign_bit), one),
                                        _mm256_cmp_pd(dv, zero, _CMP_NEQ_OQ));
        const __m256d w0 = _mm256_loadu_pd(KERNEL + i + 1), w1 = _mm256_loadu_pd(KERNEL + i);
        a0 = _mm256_fmadd_pd(w0, da, a0); a1 = _mm256_fmadd_pd(w1, da, a1);
        v0 = _mm256_fmadd_pd(w0, dv, v0); v1 = _mm256_fmadd_pd(w1, dv, v1);
        s0 = _mm256_fmadd_pd(w0, s, s0); s1 = _mm256_fmadd_pd(w1, s, s1);
        y0 = _mm256_fmadd_pd(w0, y, y0); y1 = _mm256_fmadd_pd(w1, y, y1);
    }
    _mm256_storeu_pd(lane[0], a0); _mm256_storeu_pd(lane[1], a1);
    _mm256_storeu_pd(lane[2], v0); _mm256_storeu_pd(lane[3], v1);
    _mm256_storeu_pd(lane[4], s0); _mm256_storeu_pd(lane[5], s1);
    _mm256_storeu_pd(lane[6], y0); _mm256_storeu_pd(lane[7], y1);
    for (j = 0; j < 8; ++j)
        sum[j] = (lane[j][0] + lane[j][1]) + (lane[j][2] + lane[j][3]);
    /* the last instants when 2 HALF + 2 is not a multiple of 4 (a constant start: with an open
     * one, gcc -ffast-math warned of a loop it had misread) */
    for (i = 4 * ((2 * HALF + 2) / 4); i < 2 * HALF + 2; ++i) {
        const double *q = r + i - HALF;
        const double dv = q[1] - q[-1], da = (q[1] - 2.0 * q[0]) + q[-1];
        const double s = dv > 0.0 ? 1.0 : (dv < 0.0 ? -1.0 : 0.0);
        const double w0 = KERNEL[i + 1], w1 = KERNEL[i];
        sum[0] += w0 * da; sum[1] += w1 * da; sum[2] += w0 * dv; sum[3] += w1 * dv;
        sum[4] += w0 * s; sum[5] += w1 * s; sum[6] += w0 * q[0]; sum[7] += w1 * q[0];
    }
    f0[0] = sum[0] * INV_TS2; f0[1] = sum[2] * INV_2TS; f0[2] = sum[4]; f0[3] = sum[6];
    f1[0] = sum[1] * INV_TS2; f1[1] = sum[3] * INV_2TS; f1[2] = sum[5]; f1[3] = sum[7];
}
#endif
