"""The SG fit of a measured BRDF (Wang 2009 §4.1–4.2, `measured.fit_sg`): the weighted least-squares sums
over the fit's samples, for a batch of candidates of one or two lobes (sharpness η = 2/m², Schlick's f0).

Twin of ``cl/sgfit.cl``; the float64 reference is ``measured.fit_sums``. Each sample s carries its basis
values [d_s, 1 − cos θh, (1 − h·ωi)^5, G_s/π] (d_s = cosθi·cosθo/π, the diffuse basis), its target
f·cosθi·cosθo per channel and its weight (the bin's measure). For a lobe (η, f0) the specular basis is
b_s = (f0 + (1 − f0)(1 − h·ωi)^5)·(G_s/π)·exp(−η(1 − cos θh)). A candidate is [η1, f0_1, η2, f0_2]; its
second lobe is absent (b2 = 0) where η2 ≤ 0. One thread sums `chunk` samples:

- `fit_gram`: the normal equations of the fit's three non-negative coefficients per channel (kd, ks1, ks2),
  [Σw d², Σw d b1, Σw d b2, Σw b1², Σw b1 b2, Σw b2², Σw d t_c (3), Σw b1 t_c (3), Σw b2 t_c (3)], solved on
  the host;
- `fit_residual`: Σ w Σ_c (t_c − kd_c d − ks1_c b1 − ks2_c b2)² for the coefficients found: the objective
  itself, summed term by term (not from the normal equations, whose float32 sums would cancel where the fit
  is good).

The host adds the chunks' partial sums in float64.
"""

import warp as wp

# Nothing here is differentiated: no backward kernels, which take most of the compile time.
wp.set_module_options({"enable_backward": False})


@wp.func
def specular_basis(basis: wp.array2d(dtype=wp.float32), s: int, eta: float, f0: float):
    if eta <= 0.0:  # an absent lobe
        return 0.0
    fresnel = f0 + (1.0 - f0) * basis[s, 2]
    return fresnel * basis[s, 3] * wp.exp(-eta * basis[s, 1])


@wp.kernel
def fit_gram(
    basis: wp.array2d(dtype=wp.float32),  # (N, 4)
    target: wp.array2d(dtype=wp.float32),  # (N, 3)
    weight: wp.array(dtype=wp.float32),  # (N,)
    candidates: wp.array2d(dtype=wp.float32),  # (C, 4) [η1, f0_1, η2, f0_2]
    n: int,
    chunk: int,
    offset: int,
    out: wp.array3d(dtype=wp.float32),  # (C, chunks, 15)
):
    c, k_local = wp.tid()
    k = k_local + offset
    eta1 = candidates[c, 0]
    f01 = candidates[c, 1]
    eta2 = candidates[c, 2]
    f02 = candidates[c, 3]
    dd = float(0.0)
    d1 = float(0.0)
    d2 = float(0.0)
    b11 = float(0.0)
    b12 = float(0.0)
    b22 = float(0.0)
    dt = wp.vec3(0.0, 0.0, 0.0)
    b1t = wp.vec3(0.0, 0.0, 0.0)
    b2t = wp.vec3(0.0, 0.0, 0.0)
    start = k * chunk
    end = wp.min(start + chunk, n)
    for s in range(start, end):
        w = weight[s]
        d = basis[s, 0]
        b1 = specular_basis(basis, s, eta1, f01)
        b2 = specular_basis(basis, s, eta2, f02)
        t = wp.vec3(target[s, 0], target[s, 1], target[s, 2])
        dd += w * d * d
        d1 += w * d * b1
        d2 += w * d * b2
        b11 += w * b1 * b1
        b12 += w * b1 * b2
        b22 += w * b2 * b2
        dt += (w * d) * t
        b1t += (w * b1) * t
        b2t += (w * b2) * t
    out[c, k, 0] = dd
    out[c, k, 1] = d1
    out[c, k, 2] = d2
    out[c, k, 3] = b11
    out[c, k, 4] = b12
    out[c, k, 5] = b22
    for i in range(3):
        out[c, k, 6 + i] = dt[i]
        out[c, k, 9 + i] = b1t[i]
        out[c, k, 12 + i] = b2t[i]


@wp.kernel
def fit_residual(
    basis: wp.array2d(dtype=wp.float32),  # (N, 4)
    target: wp.array2d(dtype=wp.float32),  # (N, 3)
    weight: wp.array(dtype=wp.float32),  # (N,)
    candidates: wp.array2d(dtype=wp.float32),  # (C, 4) [η1, f0_1, η2, f0_2]
    coef: wp.array2d(dtype=wp.float32),  # (C, 9) [kd RGB, ks1 RGB, ks2 RGB]
    n: int,
    chunk: int,
    offset: int,
    out: wp.array2d(dtype=wp.float32),  # (C, chunks)
):
    c, k_local = wp.tid()
    k = k_local + offset
    eta1 = candidates[c, 0]
    f01 = candidates[c, 1]
    eta2 = candidates[c, 2]
    f02 = candidates[c, 3]
    kd = wp.vec3(coef[c, 0], coef[c, 1], coef[c, 2])
    ks1 = wp.vec3(coef[c, 3], coef[c, 4], coef[c, 5])
    ks2 = wp.vec3(coef[c, 6], coef[c, 7], coef[c, 8])
    total = float(0.0)
    start = k * chunk
    end = wp.min(start + chunk, n)
    for s in range(start, end):
        d = basis[s, 0]
        b1 = specular_basis(basis, s, eta1, f01)
        b2 = specular_basis(basis, s, eta2, f02)
        r = wp.vec3(target[s, 0], target[s, 1], target[s, 2]) - d * kd - b1 * ks1 - b2 * ks2
        total += weight[s] * wp.dot(r, r)
    out[c, k] = total
