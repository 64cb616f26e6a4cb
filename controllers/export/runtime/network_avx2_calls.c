
static double network1_avx2(const double f[4])
{
    double out[1];
    network_avx2(f, out);
    return out[0];
}
#define NETWORK_AVX2(f) network1_avx2(f)
#define NETWORK2_AVX2(f0, f1, out) network2_avx2(f0, f1, out)
