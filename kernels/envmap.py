"""The prefiltered environment (Wang 2009 Eq. 34–35): one level Λ(p, η) of an equirect map.

Twin of ``cl/envmap.cl``; the mathematics is ``warp_biscale.reference.prefilter_level``, the host
side (levels, resolutions, downsampled inputs) is ``warp_biscale.lighting.prefilter``.

One thread per output texel p (no atomics) sums Σ_t G(ω_t; p, η)·L_t·Ω_t and Σ_t G·Ω_t over the
input texels t and writes their ratio. Only texels inside the lobe's support are visited:
G = exp(−η(1 − ω·p)) < 1e−7 is dropped, i.e. ω·p < cos_min = 1 − 16.118/η. The rows that can reach
it are |θ − θp| ≤ arccos(cos_min); in row θ the columns are |φ − φp| ≤ arccos(x) with
x = (cos_min − cos θ cos θp)/(sin θ sin θp) (x > 1: none, x ≤ −1: the whole row). So a thread's work
is the number of input texels in its lobe's support, not the whole map. A support holding no texel
centre (η far beyond the input's resolution) gives the nearest texel's radiance, the limit η → ∞.

Precision: 1 − ω·p is taken as ‖ω − p‖²/2 (no cancellation for sharp lobes, where η(1 − ω·p) would
otherwise carry η·6e−8 of noise); each row is summed in float32 (at most w_in positive terms) and
rows are added in float64, as in ``kernels/truth.py``. Tables (host, float64 → float32,
``lighting.equirect_tables``): rows [cos θ, sin θ, θ, Ω] per texel row (Ω: one texel's solid
angle), columns [cos φ, sin φ, φ].
"""

import warp as wp

# Nothing here is differentiated: no backward kernels, which take most of the compile time.
wp.set_module_options({"enable_backward": False})

TWO_PI = wp.constant(6.283185307179586)
PI = wp.constant(3.141592653589793)


@wp.kernel
def prefilter_level(
    radiance: wp.array(dtype=wp.vec3),  # (h_in·w_in,) row-major
    in_rows: wp.array(dtype=wp.vec4),  # (h_in,) [cos θ, sin θ, θ, Ω]
    in_cols: wp.array(dtype=wp.vec3),  # (w_in,) [cos φ, sin φ, φ]
    out_rows: wp.array(dtype=wp.vec4),  # (h_out,)
    out_cols: wp.array(dtype=wp.vec3),  # (w_out,)
    sharpness: float,
    cos_min: float,
    offset: int,
    out: wp.array(dtype=wp.vec3),  # (h_out·w_out,) row-major
):
    t = wp.tid() + offset
    w_out = out_cols.shape[0]
    h_in = in_rows.shape[0]
    w_in = in_cols.shape[0]
    i = t // w_out
    j = t - i * w_out
    r = out_rows[i]
    c = out_cols[j]
    p = wp.vec3(r[1] * c[0], r[0], r[1] * c[1])
    reach = wp.acos(wp.max(cos_min, -1.0))  # angular radius of the support
    i_lo = wp.max(0, int(wp.floor((r[2] - reach) * float(h_in) / PI - 0.5)))
    i_hi = wp.min(h_in - 1, int(wp.ceil((r[2] + reach) * float(h_in) / PI - 0.5)))
    acc = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
    total = wp.float64(0.0)
    for ii in range(i_lo, i_hi + 1):
        q = in_rows[ii]
        x = (cos_min - q[0] * r[0]) / (q[1] * r[1])
        if x <= 1.0:
            j0 = int(0)
            count = w_in
            if x > -1.0:
                dphi = wp.acos(x)
                a = int(wp.ceil((c[2] - dphi) * float(w_in) / TWO_PI - 0.5))
                b = int(wp.floor((c[2] + dphi) * float(w_in) / TWO_PI - 0.5))
                if b - a + 1 < w_in:
                    j0 = a % w_in
                    if j0 < 0:
                        j0 += w_in
                    count = wp.max(b - a + 1, 0)
            row = wp.vec3(0.0)
            row_weight = float(0.0)
            base = ii * w_in
            for k in range(count):
                jj = j0 + k
                if jj >= w_in:
                    jj -= w_in
                cc = in_cols[jj]
                d = wp.vec3(q[1] * cc[0] - p[0], q[0] - p[1], q[1] * cc[1] - p[2])
                g = wp.exp(-sharpness * 0.5 * wp.dot(d, d))
                row += g * radiance[base + jj]
                row_weight += g
            omega = wp.float64(q[3])
            acc += wp.vec3d(row) * omega
            total += wp.float64(row_weight) * omega
    if total > wp.float64(0.0):
        out[t] = wp.vec3(acc / total)
    else:
        # No input texel within the support (a lobe far narrower than the input's texels, which
        # lighting.level_plan never asks for): the limit η → ∞ of the ratio, the radiance of the
        # nearest texel centre, found among the 3×3 texels around the one containing p.
        ic = wp.min(wp.max(int(wp.floor(r[2] * float(h_in) / PI)), 0), h_in - 1)
        jc = int(wp.floor(c[2] * float(w_in) / TWO_PI))
        best = float(-2.0)
        best_k = int(0)
        for ii in range(wp.max(ic - 1, 0), wp.min(ic + 1, h_in - 1) + 1):
            q = in_rows[ii]
            for dj in range(-1, 2):
                jj = (jc + dj) % w_in
                if jj < 0:
                    jj += w_in
                cc = in_cols[jj]
                cosine = q[1] * cc[0] * p[0] + q[0] * p[1] + q[1] * cc[1] * p[2]
                if cosine > best:
                    best = cosine
                    best_k = ii * w_in + jj
        out[t] = radiance[best_k]
