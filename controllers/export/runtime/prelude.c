/* The maths functions: each overridable by a macro defined before this point (-D or a wrapper
 * that includes this file), e.g. -DCLM_FF_EXP=TcExp or CMSIS-DSP's versions. */
#ifdef CLM_FF_FLOAT
#define R(x) ((float)(x))
#define MATHF(d, f) f
/* The float build reads counts: the differences are exact in integers (|counts| <=
 * CLM_FF_COUNT_MAX), then rounded once to float and scaled; no double is computed. */
#define D2(q) (((q)[1] - (q)[0]) - ((q)[0] - (q)[-1]))
#define POS_UNIT CLM_FF_COUNT_M
#define VEL(q) ((clm_ff_real)D1(q) * (clm_ff_real)(CLM_FF_COUNT_M / (2.0 * CLM_FF_TS)))
#define ACC(q) ((clm_ff_real)D2(q) * (clm_ff_real)(CLM_FF_COUNT_M / (CLM_FF_TS * CLM_FF_TS)))
#define POS(q) ((clm_ff_real)(q) * (clm_ff_real)CLM_FF_COUNT_M)
#define RHUGE HUGE_VALF
#define TINY 1e-30f
#else
#define R(x) (x)
#define MATHF(d, f) d
/* metres, differenced in the product's order (its roundings are the product's own) */
#define D2(q) (((q)[1] - 2.0 * (q)[0]) + (q)[-1])
#define POS_UNIT 1.0
#define VEL(q) (D1(q) / (2.0 * CLM_FF_TS))
#define ACC(q) (D2(q) / (CLM_FF_TS * CLM_FF_TS))
#define POS(q) (q)
#define RHUGE HUGE_VAL
#define TINY 1e-200
#endif
#define D1(q) ((q)[1] - (q)[-1])
#ifndef SIN
#define SIN MATHF(sin, sinf)
#endif
#ifndef EXP
#define EXP MATHF(exp, expf)
#endif
#ifndef POW
#define POW MATHF(pow, powf)
#endif
#ifndef FABS
#define FABS MATHF(fabs, fabsf)
#endif
#ifndef LOG1P
#define LOG1P MATHF(log1p, log1pf)
#endif
#ifndef ERF
#define ERF MATHF(erf, erff)
#endif
#ifndef SQRT
#define SQRT MATHF(sqrt, sqrtf)
#endif
#define SGN(x) ((clm_ff_real)(((x) > R(0.0)) - ((x) < R(0.0))))
#ifndef CLM_FF_INLINE
#define CLM_FF_INLINE inline /* C99; -DCLM_FF_INLINE= for a compiler without it */
#endif

/* Finite, by the exponent bits where the real type is IEEE 754 (a test that -ffast-math cannot
 * assume away), else by comparisons. */
static int is_finite_bits(clm_ff_real x)
{
#if defined(CLM_FF_FLOAT) && FLT_MANT_DIG == 24 && FLT_MAX_EXP == 128
    uint32_t b;
    memcpy(&b, &x, sizeof b);
    return (b & 0x7f800000UL) != 0x7f800000UL;
#elif !defined(CLM_FF_FLOAT) && DBL_MANT_DIG == 53 && DBL_MAX_EXP == 1024
    unsigned long long b;
    memcpy(&b, &x, sizeof b);
    return (b & 0x7ff0000000000000ULL) != 0x7ff0000000000000ULL;
#else
    return x == x && x - x == R(0.0);
#endif
}

/* x cut to +-lim (lim > 0; HUGE_VAL: none); *st gets CLM_FF_CLAMPED where it was. A NaN
 * passes unchanged (the finite checks catch it). */
static CLM_FF_INLINE clm_ff_real clip(clm_ff_real x, clm_ff_real lim, unsigned *st)
{
    if (x > lim) {
        *st |= CLM_FF_CLAMPED;
        return lim;
    }
    if (x < -lim) {
        *st |= CLM_FF_CLAMPED;
        return -lim;
    }
    return x;
}
