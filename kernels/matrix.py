"""The matrix method's M (Wu 2011 §3.5): the pre-rotated, cosine-weighted small-scale BRDF.

Twin of ``cl/matrix.cl``; the mathematics is ``warp_biscale.matrix.brdf_matrix`` (float64). One thread per
entry M[l, k] = d·f_r(n_l, ωi_k, ωo_k)(n_l·ωi_k)⁺(n_l·ωo_k)⁺: rows over normals (the octahedral texels of
the material's precomputed M, or any block of them), columns over direction pairs, d Wu §3.7's colour
direction. The BRDF is the ground truth's own dispatcher `material_cosine_weighted` (kernels/common.py: the
analytic kinds and the measured lookup of `tables`), so M weighs a normal exactly as the truth weighs a
facet. The launch is (rows, pairs), pairs last: neighbouring threads write neighbouring entries of a row,
and the CPU backend slices the pairs over its cores.
"""

import warp as wp

from .common import material_cosine_weighted

# Nothing here is differentiated: no backward kernels, which take most of the compile time.
wp.set_module_options({"enable_backward": False})


@wp.kernel
def brdf_matrix(
    normal: wp.array(dtype=wp.vec3),
    wi: wp.array(dtype=wp.vec3),
    wo: wp.array(dtype=wp.vec3),
    kinds: wp.array(dtype=wp.int32),
    params: wp.array2d(dtype=wp.float32),
    tables: wp.array(dtype=wp.float32),
    m: int,
    color: wp.vec3,
    offset: int,
    out: wp.array2d(dtype=wp.float32),
):
    l, p_local = wp.tid()
    p = p_local + offset
    # (no anisotropic kind reaches M: its rows carry no tangent, and as_material_list refuses one)
    f = material_cosine_weighted(kinds[m], params, m, normal[l], wp.vec3(1.0, 0.0, 0.0), wi[p], wo[p], tables)
    out[l, p] = color[0] * f[0] + color[1] * f[1] + color[2] * f[2]
