
/* The held force (N) of the window at r[0]; *st gets the envelope's status. */
static clm_ff_real window_force(const clm_ff_pos *r, unsigned *st)
{
    const clm_ff_real u = R(0.5) * (physical(r, st) + physical(r + 1, st));
    return is_finite_bits(u) ? u : (clm_ff_real)NAN;
}
