
/* Network force (N) of the (filtered) features f = [a, v, sign v, y]. */
static clm_ff_real network(const clm_ff_real f[4])
{
    clm_ff_real h0[4];
    clm_ff_real out = OUT_B;
    int i, o, j;
    for (i = 0; i < 4; ++i)
        h0[i] = (f[i] - IN_MEAN[i]) / IN_STD[i];
${layers}        for (i = 0; i < ${n_last}; ++i)
            out += OUT_W[i] * h${last}[i];
${closing}    return out;
}
