    {
        clm_ff_real h${next}[${n_out}];
        for (o = 0; o < ${n_out}; ++o) {
            clm_ff_real x = B${layer}[o];
            for (j = 0; j < ${n_in}; ++j)
                x += W${layer}[o][j] * h${layer}[j];
            h${next}[o] = ${activation};
        }
