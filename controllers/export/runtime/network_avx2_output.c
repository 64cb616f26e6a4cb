    acc = zero;
    for (o = 0; o < ${n_pad}; o += 4)
        acc = _mm256_fmadd_pd(_mm256_loadu_pd(OUT_WP + o), _mm256_loadu_pd(h${last}[${b}] + o), acc);
    _mm256_storeu_pd(lane, acc);
    out[${b}] = OUT_B + ((lane[0] + lane[1]) + (lane[2] + lane[3]));
