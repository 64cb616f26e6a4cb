/* Force (N) at the sample instant of r[0]: physical layer and effects. */
static CLM_FF_INLINE clm_ff_real physical(const clm_ff_pos *r)
{
    const clm_ff_real y = (clm_ff_real)POS(r[0]);
    const clm_ff_real v = (clm_ff_real)VEL(r);
    const clm_ff_real a = (clm_ff_real)ACC(r);
    clm_ff_real p = ${rigid_body};
    const clm_ff_real base = p;
    (void)base;
${effects}    return p;
}
