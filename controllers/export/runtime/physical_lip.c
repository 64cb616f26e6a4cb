/* Force (N) at the sample instant of r[0]: physical layer and effects, on the velocity and
 * acceleration cut to the envelope (*st: CLM_FF_CLAMPED where one was). */
static CLM_FF_INLINE clm_ff_real physical(const clm_ff_pos *r, unsigned *st)
{
    const clm_ff_real y = (clm_ff_real)POS(r[0]);
    const clm_ff_real v = clip((clm_ff_real)VEL(r), (clm_ff_real)CLM_FF_V_MAX, st);
    const clm_ff_real a = clip((clm_ff_real)ACC(r), (clm_ff_real)CLM_FF_A_MAX, st);
    clm_ff_real p = ${rigid_body};
    const clm_ff_real base = p;
    (void)base;
${effects}    return p;
}
