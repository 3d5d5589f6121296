/* The matrix method's M (Wu 2011 §3.5): the pre-rotated, cosine-weighted small-scale BRDF.
 *
 * Twin of kernels/matrix.py; the mathematics is warp_biscale.matrix.brdf_matrix (float64). One
 * work-item per entry M[l, k] = d·f_r(n_l, ωi_k, ωo_k)(n_l·ωi_k)⁺(n_l·ωo_k)⁺, with the ground truth's
 * dispatcher material_cosine_weighted (common.cl: the analytic kinds and the measured lookup of `tables`),
 * d Wu §3.7's colour direction.
 *
 * NDRange: (pairs, rows), dimension 0 varying fastest as the last dimension of Warp's (rows, pairs)
 * launch, rounded up to a whole work-group; the surplus work-items return. 3-vectors are float arrays
 * of stride 3; out is (rows, pairs) row-major.
 */

__kernel void brdf_matrix(
    __global const float *normal,  /* (L, 3) */
    __global const float *wi,      /* (P, 3) */
    __global const float *wo,      /* (P, 3) */
    __global const int *kinds,     /* (materials,) */
    __global const float *params,  /* (materials, 8) */
    __global const float *tables,  /* the measured BRDFs' tables (a one-float stand-in where none) */
    const int m,
    const float cr,
    const float cg,
    const float cb,
    const int n_rows,
    const int n_pairs,
    __global float *out)           /* (L, P) */
{
    int p = get_global_id(0);
    int l = get_global_id(1);
    if (p >= n_pairs || l >= n_rows)
        return;
    /* (no anisotropic kind reaches M: its rows carry no tangent, and as_material_list refuses one) */
    float3 f = material_cosine_weighted(kinds[m], params, m, load3(normal, l), (float3)(1.0f, 0.0f, 0.0f),
                                        load3(wi, p), load3(wo, p), tables);
    out[(size_t)l * n_pairs + p] = cr * f.x + cg * f.y + cb * f.z;
}
