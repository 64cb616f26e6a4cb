/* A state of the sections below 1e-200 in magnitude is set to 0. At rest after a move the
 * states of a, v and sign v decay geometrically and would turn subnormal within seconds and stay
 * (each push then some 20 % slower on x86, more elsewhere); flushed, they reach an exact 0 and
 * the outputs with them. What this changes of a force is far below its rounding. */
static CLM_FF_INLINE clm_ff_real flush_tiny(clm_ff_real z)
{
    return FABS(z) < TINY ? R(0.0) : z;
}

/* Push raw features x[4] = [a, v, sign v, y] of the newest instant through the sections. */
static void forward(clm_ff_stream *s, const clm_ff_real x[4])
{
    int c, j;
    for (c = 0; c < 4; ++c) {
        clm_ff_real xc = x[c];
        for (j = 0; j < CLM_FF_NSEC; ++j) { /* transposed direct form II, as scipy's sosfilt */
            const clm_ff_real y = SOS[j][0] * xc + s->zf[c][j][0];
            s->zf[c][j][0] = flush_tiny(SOS[j][1] * xc - SOS[j][4] * y + s->zf[c][j][1]);
            s->zf[c][j][1] = flush_tiny(SOS[j][2] * xc - SOS[j][5] * y);
            xc = y;
        }
        s->fwd[c][s->fnext] = xc;
        s->fwd[c][s->fnext + HALF + 1] = xc;
    }
    s->fnext = (s->fnext + 1) % (HALF + 1);
}

#ifdef CLM_FF_AVX2
/* The backward FIR with AVX2 and FMA: four taps at a time, two chains per feature. */
__attribute__((target("avx2,fma")))
static void backward_avx2(const double *w0, const double *w1, const double *w2,
                          const double *w3, double f[4])
{
    __m256d a0 = _mm256_setzero_pd(), v0 = a0, s0 = a0, y0 = a0;
    __m256d a1 = a0, v1 = a0, s1 = a0, y1 = a0;
    double lane[8][4];
    int i, j;
    for (i = 0; i + 8 <= HALF + 1; i += 8) {
        const __m256d g0 = _mm256_loadu_pd(BACK + i), g1 = _mm256_loadu_pd(BACK + i + 4);
        a0 = _mm256_fmadd_pd(g0, _mm256_loadu_pd(w0 + i), a0);
        v0 = _mm256_fmadd_pd(g0, _mm256_loadu_pd(w1 + i), v0);
        s0 = _mm256_fmadd_pd(g0, _mm256_loadu_pd(w2 + i), s0);
        y0 = _mm256_fmadd_pd(g0, _mm256_loadu_pd(w3 + i), y0);
        a1 = _mm256_fmadd_pd(g1, _mm256_loadu_pd(w0 + i + 4), a1);
        v1 = _mm256_fmadd_pd(g1, _mm256_loadu_pd(w1 + i + 4), v1);
        s1 = _mm256_fmadd_pd(g1, _mm256_loadu_pd(w2 + i + 4), s1);
        y1 = _mm256_fmadd_pd(g1, _mm256_loadu_pd(w3 + i + 4), y1);
    }
    _mm256_storeu_pd(lane[0], _mm256_add_pd(a0, a1));
    _mm256_storeu_pd(lane[1], _mm256_add_pd(v0, v1));
    _mm256_storeu_pd(lane[2], _mm256_add_pd(s0, s1));
    _mm256_storeu_pd(lane[3], _mm256_add_pd(y0, y1));
    for (j = 0; j < 4; ++j)
        f[j] = (lane[j][0] + lane[j][1]) + (lane[j][2] + lane[j][3]);
    for (; i <= HALF; ++i) {
        f[0] += BACK[i] * w0[i]; f[1] += BACK[i] * w1[i];
        f[2] += BACK[i] * w2[i]; f[3] += BACK[i] * w3[i];
    }
}
#endif

/* The backward FIR over the forward outputs held: the filtered features f. */
static void backward(const clm_ff_stream *s, clm_ff_real f[4])
{
    const clm_ff_real *w0 = s->fwd[0] + s->fnext, *w1 = s->fwd[1] + s->fnext;
    const clm_ff_real *w2 = s->fwd[2] + s->fnext, *w3 = s->fwd[3] + s->fnext;
    clm_ff_real a0 = R(0.0), v0 = R(0.0), s0 = R(0.0), y0 = R(0.0);
    clm_ff_real a1 = R(0.0), v1 = R(0.0), s1 = R(0.0), y1 = R(0.0);
    int i;
#ifdef CLM_FF_AVX2
    if (CLM_FF_HAS_AVX2()) {
        backward_avx2(w0, w1, w2, w3, f);
        return;
    }
#endif
    for (i = 0; i + 1 <= HALF; i += 2) { /* two chains per feature: the additions overlap */
        const clm_ff_real g0 = BACK[i], g1 = BACK[i + 1];
        a0 += g0 * w0[i]; v0 += g0 * w1[i];
        s0 += g0 * w2[i]; y0 += g0 * w3[i];
        a1 += g1 * w0[i + 1]; v1 += g1 * w1[i + 1];
        s1 += g1 * w2[i + 1]; y1 += g1 * w3[i + 1];
    }
    for (; i <= HALF; ++i) {
        a0 += BACK[i] * w0[i]; v0 += BACK[i] * w1[i];
        s0 += BACK[i] * w2[i]; y0 += BACK[i] * w3[i];
    }
    f[0] = a0 + a1; f[1] = v0 + v1; f[2] = s0 + s1; f[3] = y0 + y1;
}

/* Force at the oldest instant of the forward outputs held; *st gets CLM_FF_CLAMPED where the
 * features were cut to the envelope. */
static clm_ff_real stream_point(const clm_ff_stream *s, unsigned *st)
{
    clm_ff_real f[4];
    backward(s, f);
    clip_features(f, st);
#ifdef CLM_FF_AVX2
    if (CLM_FF_HAS_AVX2())
        return physical(f) + NETWORK_AVX2(f);
#endif
    return physical(f) + network(f);
}

/* The raw features [a, v, sign v, y] of the instant n[0], as the product differences. */
static void differences(const clm_ff_pos *n, clm_ff_real x[4])
{
    x[1] = (clm_ff_real)VEL(n);
    x[0] = (clm_ff_real)ACC(n);
    x[2] = x[1] > R(0.0) ? R(1.0) : (x[1] < R(0.0) ? R(-1.0) : R(0.0));
    x[3] = (clm_ff_real)POS(n[0]);
}

/* The sections in their steady state for the constant features x. */
static void steady(clm_ff_stream *s, const clm_ff_real x[4])
{
    int j, c;
    for (c = 0; c < 4; ++c)
        for (j = 0; j < CLM_FF_NSEC; ++j) {
            s->zf[c][j][0] = SOS_ZI[j][0] * x[c];
            s->zf[c][j][1] = SOS_ZI[j][1] * x[c];
        }
}

unsigned clm_ff_stream_init(clm_ff_stream *s, clm_ff_pos r0)
{
    clm_ff_real x[4];
    unsigned st = CLM_FF_OK;
    int i;
    if (!sample_ok(r0))
        return stop(s);
    fill_at_rest(s, r0);
    /* at rest: a = v = sign v = 0, y = r0; the sections in their steady state */
    x[0] = x[1] = x[2] = R(0.0);
    x[3] = (clm_ff_real)POS(r0);
    steady(s, x);
    for (i = 0; i < 2 * (HALF + 1); ++i) {
        s->fwd[0][i] = s->fwd[1][i] = s->fwd[2][i] = R(0.0);
        s->fwd[3][i] = x[3];
    }
    s->fnext = 0;
    s->p_next = stream_point(s, &st);
    reset(s, s->p_next);
    return CLM_FF_OK;
}

unsigned clm_ff_stream_start(clm_ff_stream *s, const clm_ff_pos *r, clm_ff_real *u_ff)
{
    clm_ff_real x[4], p;
    unsigned st = CLM_FF_OK;
    int i;
    if (!window_ok(r))
        return stop(s);
    fill_window(s, r);
    /* The sections started in the steady state of the oldest instant's features, then run over
     * the window's 2 HALF + 2 instants: what they forget of that start decays as the filter's
     * impulse response, below the export's tolerance after HALF samples. */
    differences(r - HALF, x);
    steady(s, x);
    s->fnext = 0;
    for (i = -HALF; i <= HALF; ++i) {
        differences(r + i, x);
        forward(s, x);
    }
    p = stream_point(s, &st);            /* force at k */
    differences(r + HALF + 1, x);
    forward(s, x);
    s->p_next = stream_point(s, &st);    /* force at k+1 */
    *u_ff = R(0.5) * (p + s->p_next);
    reset(s, *u_ff);
    return st;
}

/* One push before the limits: the force (N) and *st. */
static CLM_FF_INLINE clm_ff_real advance(clm_ff_stream *s, clm_ff_pos r_newest, unsigned *st)
{
    const clm_ff_pos *r;
    clm_ff_real x[4], p, u;
    r_newest = accept(s, r_newest, st);
    s->buf[s->next] = r_newest;
    s->buf[s->next + CLM_FF_WINDOW] = r_newest;
    s->next = (s->next + 1) % CLM_FF_WINDOW;
    r = &s->buf[s->next + CLM_FF_LAG];   /* r[k] */
    differences(r + CLM_FF_LAG, x);      /* r[k + HALF + 1]: the newest instant with differences */
    forward(s, x);                       /* forward outputs now cover k+1 .. k+HALF+1 */
    p = stream_point(s, st);             /* force at k+1 */
    u = R(0.5) * (s->p_next + p);
    s->p_next = p;
    return u;
}
