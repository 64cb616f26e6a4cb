
clm_ff_real clm_ff(const clm_ff_pos *r)
{
    const clm_ff_real u = R(0.5) * (physical(r) + physical(r + 1));
    return is_finite_bits(u) ? u : (clm_ff_real)NAN;
}
