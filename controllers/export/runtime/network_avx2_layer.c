    for (o = 0; o < ${n_pad}; o += 4) {
${start}        for (j = 0; j < ${n_in}; ++j) {
            const __m256d w = _mm256_loadu_pd(W${layer}T[j] + o);
${fma}        }
${store}    }
