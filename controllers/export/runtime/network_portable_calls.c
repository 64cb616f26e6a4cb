
#ifdef CLM_FF_AVX2
#define NETWORK_AVX2(f) network(f)
#define NETWORK2_AVX2(f0, f1, out) ((out)[0] = network(f0), (out)[1] = network(f1))
#endif
