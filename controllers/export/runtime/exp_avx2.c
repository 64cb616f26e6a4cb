
/* e^x, four at a time, to about 2 ulp: x = n ln2 + t, |t| <= ln2/2 (ln2 in two parts, fdlibm's),
 * e^t by its Taylor series to t^13 (truncation below 1e-17), times 2^n built in the exponent
 * bits. x is clamped to +-708 (a tanh or a sigmoid is already at its limit there); NaN stays
 * NaN (as libm's exp). */
__attribute__((target("avx2,fma")))
static __m256d exp_avx2(__m256d x)
{
    static const double c[14] = {
        1.0, 1.0, 1.0 / 2, 1.0 / 6, 1.0 / 24, 1.0 / 120, 1.0 / 720, 1.0 / 5040, 1.0 / 40320,
        1.0 / 362880, 1.0 / 3628800, 1.0 / 39916800, 1.0 / 479001600, 1.0 / 6227020800.0};
    __m256d n, t, p;
    __m256i e;
    int i;
    /* max and min return their second operand where one is NaN: x second, so NaN stays NaN */
    x = _mm256_min_pd(_mm256_set1_pd(708.0), _mm256_max_pd(_mm256_set1_pd(-708.0), x));
    n = _mm256_round_pd(_mm256_mul_pd(x, _mm256_set1_pd(1.4426950408889634)),
                        _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
    t = _mm256_fnmadd_pd(n, _mm256_set1_pd(6.93147180369123816490e-01), x);
    t = _mm256_fnmadd_pd(n, _mm256_set1_pd(1.90821492927058770002e-10), t);
    p = _mm256_set1_pd(c[13]);
    for (i = 12; i >= 0; --i)
        p = _mm256_fmadd_pd(p, t, _mm256_set1_pd(c[i]));
    e = _mm256_slli_epi64(_mm256_add_epi64(_mm256_cvtepi32_epi64(_mm256_cvtpd_epi32(n)),
                                           _mm256_set1_epi64x(1023)), 52);
    return _mm256_mul_pd(p, _mm256_castsi256_pd(e));
}
