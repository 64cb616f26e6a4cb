
/* A second path with AVX2 and FMA, four values at a time: the filter sums and the network
 * (clm_ff about 4 times faster, the stream 2). clm_ff and the streaming form take it where the
 * CPU has both (checked at every call: a load and a test). It needs GCC or Clang on x86-64;
 * -DCLM_FF_PORTABLE (or -DCLM_FF_FLOAT) keeps the portable C only. The two paths agree to
 * rounding (~1e-15 of the peak force). */
#if !defined(CLM_FF_FLOAT) && !defined(CLM_FF_PORTABLE) && \
    (defined(__GNUC__) || defined(__clang__)) && defined(__x86_64__)
#define CLM_FF_AVX2 1
#include <immintrin.h>
#define CLM_FF_HAS_AVX2() (__builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma"))
#endif
