/* Facet sampling (Wu §3.2, stratified): one work-item per facet.
 *
 * Twin of kernels/facets.py; the mathematics is warp_biscale.reference.sample_facets: facet s
 * takes u1 = (s + xi1)/Ns along the cumulative face area (float64, so a face is found exactly even
 * among 10^6 faces) and u2 = frac(phi2(s) + xi2), mapped into its face by the area-preserving
 * square->triangle map. Needs cl_khr_fp64. 3-vectors are float arrays of stride 3.
 */
#pragma OPENCL EXTENSION cl_khr_fp64 : enable

/* Van der Corput phi2(s) on the top 24 bits, exact in float32. */
CL_INLINE float radical_inverse_24(int s)
{
    uint x = (uint)s;
    x = ((x >> 1) & 0x55555555u) | ((x & 0x55555555u) << 1);
    x = ((x >> 2) & 0x33333333u) | ((x & 0x33333333u) << 2);
    x = ((x >> 4) & 0x0F0F0F0Fu) | ((x & 0x0F0F0F0Fu) << 4);
    x = ((x >> 8) & 0x00FF00FFu) | ((x & 0x00FF00FFu) << 8);
    x = (x >> 16) | (x << 16);
    return (float)(x >> 8) * (1.0f / 16777216.0f);
}

__kernel void sample_facets(
    __global const float *vertices,        /* (V, 3) */
    __global const int *faces,             /* (F, 3) */
    __global const float *vertex_normals,  /* (V, 3), or one dummy row */
    const int use_vertex_normals,
    __global const float *face_normals,    /* (F, 3) */
    __global const double *cumulative_area,/* (F,) */
    __global const double *face_area,      /* (F,) */
    const int n_faces,
    const int count,
    const double xi1,
    const float xi2,
    __global float *position,              /* (count, 3) */
    __global float *normal,                /* (count, 3) */
    __global int *face)                    /* (count,) */
{
    int s = get_global_id(0);
    if (s >= count)
        return;
    double total = cumulative_area[n_faces - 1];
    double target = ((double)s + xi1) / (double)count * total;
    /* First face whose cumulative area exceeds the target. */
    int lo = 0;
    int hi = n_faces - 1;
    while (lo < hi) {
        int mid = (lo + hi) / 2;
        if (cumulative_area[mid] > target)
            hi = mid;
        else
            lo = mid + 1;
    }
    int f = lo;
    double start = cumulative_area[f] - face_area[f];
    float u = (float)clamp((target - start) / face_area[f], 0.0, 1.0);
    float v = radical_inverse_24(s) + xi2;
    if (v >= 1.0f)
        v = v - 1.0f;
    float su = sqrt(u);
    float b0 = 1.0f - su;
    float b1 = su * (1.0f - v);
    float b2 = su * v;
    int i0 = faces[3 * f + 0];
    int i1 = faces[3 * f + 1];
    int i2 = faces[3 * f + 2];
    float3 p0 = load3(vertices, i0);
    float3 p1 = load3(vertices, i1);
    float3 p2 = load3(vertices, i2);
    store3(position, s, (float3)(b0 * p0.x + b1 * p1.x + b2 * p2.x,
                                 b0 * p0.y + b1 * p1.y + b2 * p2.y,
                                 b0 * p0.z + b1 * p1.z + b2 * p2.z));
    if (use_vertex_normals != 0) {
        float3 n0 = load3(vertex_normals, i0);
        float3 n1 = load3(vertex_normals, i1);
        float3 n2 = load3(vertex_normals, i2);
        store3(normal, s, normalize3((float3)(b0 * n0.x + b1 * n1.x + b2 * n2.x,
                                             b0 * n0.y + b1 * n1.y + b2 * n2.y,
                                             b0 * n0.z + b1 * n1.z + b2 * n2.z)));
    } else {
        store3(normal, s, load3(face_normals, f));
    }
    face[s] = f;
}

/* A facet's weight from its face's value: per_face[face] * dA (bake._channel_faces' colour channels, made where the
 * facets are, so the host neither reads their faces back nor uploads a weight a facet). */
__kernel void facet_weights(
    __global const int *face,
    __global const float *per_face,
    __global const float *area,
    const int count,
    __global float *weight)
{
    int s = get_global_id(0);
    if (s >= count)
        return;
    weight[s] = per_face[face[s]] * area[s];
}
