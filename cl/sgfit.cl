/* The SG fit of a measured BRDF (Wang 2009 §4.1–4.2, measured.fit_sg): the weighted least-squares sums over
 * the fit's samples for a batch of candidates of one or two lobes (sharpness η = 2/m², Schlick's f0).
 *
 * Twin of kernels/sgfit.py (which says what the sums are); the float64 reference is measured.fit_sums.
 * basis (N, 4) [d, 1 − cos θh, (1 − h·ωi)^5, G/π], target (N, 3), weight (N,), candidates (C, 4)
 * [η1, f0_1, η2, f0_2]: the second lobe is absent (b2 = 0) where η2 <= 0.
 *
 * NDRange: (chunks, candidates), dimension 0 varying fastest as the last dimension of Warp's
 * (candidates, chunks) launch, rounded up to a whole work-group; the surplus work-items return.
 */

static float specular_basis(__global const float *basis, int s, float eta, float f0)
{
    if (eta <= 0.0f)  /* an absent lobe */
        return 0.0f;
    float fresnel = f0 + (1.0f - f0) * basis[4 * s + 2];
    return fresnel * basis[4 * s + 3] * exp(-eta * basis[4 * s + 1]);
}

__kernel void fit_gram(
    __global const float *basis,       /* (N, 4) */
    __global const float *target,      /* (N, 3) */
    __global const float *weight,      /* (N,) */
    __global const float *candidates,  /* (C, 4) */
    const int n,
    const int chunk,
    const int n_chunks,
    const int n_candidates,
    __global float *out)               /* (C, chunks, 15) */
{
    int k = get_global_id(0);
    int c = get_global_id(1);
    if (k >= n_chunks || c >= n_candidates)
        return;
    float eta1 = candidates[4 * c], f01 = candidates[4 * c + 1];
    float eta2 = candidates[4 * c + 2], f02 = candidates[4 * c + 3];
    float dd = 0.0f, d1 = 0.0f, d2 = 0.0f, b11 = 0.0f, b12 = 0.0f, b22 = 0.0f;
    float3 dt = (float3)(0.0f), b1t = (float3)(0.0f), b2t = (float3)(0.0f);
    int end = min(k * chunk + chunk, n);
    for (int s = k * chunk; s < end; s++) {
        float w = weight[s];
        float d = basis[4 * s];
        float b1 = specular_basis(basis, s, eta1, f01);
        float b2 = specular_basis(basis, s, eta2, f02);
        float3 t = (float3)(target[3 * s], target[3 * s + 1], target[3 * s + 2]);
        dd += w * d * d;
        d1 += w * d * b1;
        d2 += w * d * b2;
        b11 += w * b1 * b1;
        b12 += w * b1 * b2;
        b22 += w * b2 * b2;
        dt += (w * d) * t;
        b1t += (w * b1) * t;
        b2t += (w * b2) * t;
    }
    __global float *o = out + ((size_t)c * n_chunks + k) * 15;
    o[0] = dd; o[1] = d1; o[2] = d2; o[3] = b11; o[4] = b12; o[5] = b22;
    o[6] = dt.x; o[7] = dt.y; o[8] = dt.z;
    o[9] = b1t.x; o[10] = b1t.y; o[11] = b1t.z;
    o[12] = b2t.x; o[13] = b2t.y; o[14] = b2t.z;
}

__kernel void fit_residual(
    __global const float *basis,       /* (N, 4) */
    __global const float *target,      /* (N, 3) */
    __global const float *weight,      /* (N,) */
    __global const float *candidates,  /* (C, 4) */
    __global const float *coef,        /* (C, 9) [kd RGB, ks1 RGB, ks2 RGB] */
    const int n,
    const int chunk,
    const int n_chunks,
    const int n_candidates,
    __global float *out)               /* (C, chunks) */
{
    int k = get_global_id(0);
    int c = get_global_id(1);
    if (k >= n_chunks || c >= n_candidates)
        return;
    float eta1 = candidates[4 * c], f01 = candidates[4 * c + 1];
    float eta2 = candidates[4 * c + 2], f02 = candidates[4 * c + 3];
    float3 kd = (float3)(coef[9 * c], coef[9 * c + 1], coef[9 * c + 2]);
    float3 ks1 = (float3)(coef[9 * c + 3], coef[9 * c + 4], coef[9 * c + 5]);
    float3 ks2 = (float3)(coef[9 * c + 6], coef[9 * c + 7], coef[9 * c + 8]);
    float total = 0.0f;
    int end = min(k * chunk + chunk, n);
    for (int s = k * chunk; s < end; s++) {
        float d = basis[4 * s];
        float b1 = specular_basis(basis, s, eta1, f01);
        float b2 = specular_basis(basis, s, eta2, f02);
        float3 r = (float3)(target[3 * s], target[3 * s + 1], target[3 * s + 2]) - d * kd - b1 * ks1 - b2 * ks2;
        total += weight[s] * dot(r, r);
    }
    out[(size_t)c * n_chunks + k] = total;
}
