/* 1/ts^2 and 1/(2 ts) per unit of the differences (m, or counts in the float build) */
static const clm_ff_real INV_TS2 = (clm_ff_real)(POS_UNIT / (CLM_FF_TS * CLM_FF_TS));
static const clm_ff_real INV_2TS = (clm_ff_real)(POS_UNIT / (2.0 * CLM_FF_TS));
