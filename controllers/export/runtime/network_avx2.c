
/* network() with AVX2 and FMA at ${count} instant(s): out[b] from f<b>. */
__attribute__((target("avx2,fma")))
static void ${name}(${args})
{
    const __m256d one = _mm256_set1_pd(1.0), two = _mm256_set1_pd(2.0);
    const __m256d zero = _mm256_setzero_pd();
    __m256d acc;
    double h0[${count}][4], lane[4];
${hidden}    int i, j, o;
    (void)one; (void)two;
    for (i = 0; i < 4; ++i) {
${norm}    }
${layers}${outputs}}
