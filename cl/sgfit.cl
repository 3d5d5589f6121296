/* The SG fit of a measured BRDF (Wang 2009 §4.1–4.2, measured.fit_sg): the weighted least-squares sums over
 * the fit's samples for a batch of candidate lobes (sharpness η = 2/m², Schlick's f0).
 *
 * Twin of kernels/sgfit.py (which says what the sums are); the float64 reference is measured.fit_sums.
 * basis (N, 4) [d, 1 − cos θh, (1 − h·ωi)^5, G/π], target (N, 3), weight (N,), candidates (C, 2) [η, f0].
 *
 * NDRange: (chunks, candidates), dimension 0 varying fastest as the last dimension of Warp's
 * (candidates, chunks) launch, rounded up to a whole work-group; the surplus work-items return.
 */

static float specular_basis(__global const float *basis, int s, float eta, float f0)
{
    float fresnel = f0 + (1.0f - f0) * basis[4 * s + 2];
    return fresnel * basis[4 * s + 3] * exp(-eta * basis[4 * s + 1]);
}

__kernel void fit_gram(
    __global const float *basis,       /* (N, 4) */
    __global const float *target,      /* (N, 3) */
    __global const float *weight,      /* (N,) */
    __global const float *candidates,  /* (C, 2) */
    const int n,
    const int chunk,
    const int n_chunks,
    const int n_candidates,
    __global float *out)               /* (C, chunks, 9) */
{
    int k = get_global_id(0);
    int c = get_global_id(1);
    if (k >= n_chunks || c >= n_candidates)
        return;
    float eta = candidates[2 * c], f0 = candidates[2 * c + 1];
    float dd = 0.0f, db = 0.0f, bb = 0.0f;
    float3 dt = (float3)(0.0f), bt = (float3)(0.0f);
    int end = min(k * chunk + chunk, n);
    for (int s = k * chunk; s < end; s++) {
        float w = weight[s];
        float d = basis[4 * s];
        float b = specular_basis(basis, s, eta, f0);
        float3 t = (float3)(target[3 * s], target[3 * s + 1], target[3 * s + 2]);
        dd += w * d * d;
        db += w * d * b;
        bb += w * b * b;
        dt += (w * d) * t;
        bt += (w * b) * t;
    }
    __global float *o = out + ((size_t)c * n_chunks + k) * 9;
    o[0] = dd; o[1] = db; o[2] = bb;
    o[3] = dt.x; o[4] = dt.y; o[5] = dt.z;
    o[6] = bt.x; o[7] = bt.y; o[8] = bt.z;
}

__kernel void fit_residual(
    __global const float *basis,       /* (N, 4) */
    __global const float *target,      /* (N, 3) */
    __global const float *weight,      /* (N,) */
    __global const float *candidates,  /* (C, 2) */
    __global const float *coef,        /* (C, 6) [kd R, G, B, ks R, G, B] */
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
    float eta = candidates[2 * c], f0 = candidates[2 * c + 1];
    float3 kd = (float3)(coef[6 * c], coef[6 * c + 1], coef[6 * c + 2]);
    float3 ks = (float3)(coef[6 * c + 3], coef[6 * c + 4], coef[6 * c + 5]);
    float total = 0.0f;
    int end = min(k * chunk + chunk, n);
    for (int s = k * chunk; s < end; s++) {
        float d = basis[4 * s];
        float b = specular_basis(basis, s, eta, f0);
        float3 r = (float3)(target[3 * s], target[3 * s + 1], target[3 * s + 2]) - d * kd - b * ks;
        total += weight[s] * dot(r, r);
    }
    out[(size_t)c * n_chunks + k] = total;
}
