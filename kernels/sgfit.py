"""The SG fit of a measured BRDF (Wang 2009 §4.1–4.2, `measured.fit_sg`): the weighted least-squares sums
over the fit's samples, for a batch of candidate lobes (sharpness η = 2/m², Schlick's f0).

Twin of ``cl/sgfit.cl``; the float64 reference is ``measured.fit_sums``. Each sample s carries its basis
values [d_s, 1 − cos θh, (1 − h·ωi)^5, G_s/π] (d_s = cosθi·cosθo/π, the diffuse basis), its target
f·cosθi·cosθo per channel and its weight (the bin's measure). For a candidate (η, f0) the specular basis is
b_s = (f0 + (1 − f0)(1 − h·ωi)^5)·(G_s/π)·exp(−η(1 − cos θh)), and one thread sums `chunk` samples:

- `fit_gram`: Σ w d², Σ w d b, Σ w b², Σ w d t_c (c = R, G, B), Σ w b t_c — the normal equations of the
  fit's two non-negative coefficients per channel, solved on the host;
- `fit_residual`: Σ w Σ_c (t_c − kd_c d − ks_c b)² for the coefficients found: the objective itself, summed
  term by term (not from the normal equations, whose float32 sums would cancel where the fit is good).

The host adds the chunks' partial sums in float64.
"""

import warp as wp


@wp.func
def specular_basis(basis: wp.array2d(dtype=wp.float32), s: int, eta: float, f0: float):
    fresnel = f0 + (1.0 - f0) * basis[s, 2]
    return fresnel * basis[s, 3] * wp.exp(-eta * basis[s, 1])


@wp.kernel
def fit_gram(
    basis: wp.array2d(dtype=wp.float32),  # (N, 4)
    target: wp.array2d(dtype=wp.float32),  # (N, 3)
    weight: wp.array(dtype=wp.float32),  # (N,)
    candidates: wp.array2d(dtype=wp.float32),  # (C, 2) [η, f0]
    n: int,
    chunk: int,
    offset: int,
    out: wp.array3d(dtype=wp.float32),  # (C, chunks, 9)
):
    c, k_local = wp.tid()
    k = k_local + offset
    eta = candidates[c, 0]
    f0 = candidates[c, 1]
    dd = float(0.0)
    db = float(0.0)
    bb = float(0.0)
    dt = wp.vec3(0.0, 0.0, 0.0)
    bt = wp.vec3(0.0, 0.0, 0.0)
    start = k * chunk
    end = wp.min(start + chunk, n)
    for s in range(start, end):
        w = weight[s]
        d = basis[s, 0]
        b = specular_basis(basis, s, eta, f0)
        t = wp.vec3(target[s, 0], target[s, 1], target[s, 2])
        dd += w * d * d
        db += w * d * b
        bb += w * b * b
        dt += (w * d) * t
        bt += (w * b) * t
    out[c, k, 0] = dd
    out[c, k, 1] = db
    out[c, k, 2] = bb
    for i in range(3):
        out[c, k, 3 + i] = dt[i]
        out[c, k, 6 + i] = bt[i]


@wp.kernel
def fit_residual(
    basis: wp.array2d(dtype=wp.float32),  # (N, 4)
    target: wp.array2d(dtype=wp.float32),  # (N, 3)
    weight: wp.array(dtype=wp.float32),  # (N,)
    candidates: wp.array2d(dtype=wp.float32),  # (C, 2) [η, f0]
    coef: wp.array2d(dtype=wp.float32),  # (C, 6) [kd R, G, B, ks R, G, B]
    n: int,
    chunk: int,
    offset: int,
    out: wp.array2d(dtype=wp.float32),  # (C, chunks)
):
    c, k_local = wp.tid()
    k = k_local + offset
    eta = candidates[c, 0]
    f0 = candidates[c, 1]
    kd = wp.vec3(coef[c, 0], coef[c, 1], coef[c, 2])
    ks = wp.vec3(coef[c, 3], coef[c, 4], coef[c, 5])
    total = float(0.0)
    start = k * chunk
    end = wp.min(start + chunk, n)
    for s in range(start, end):
        d = basis[s, 0]
        b = specular_basis(basis, s, eta, f0)
        r = wp.vec3(target[s, 0], target[s, 1], target[s, 2]) - d * kd - b * ks
        total += weight[s] * wp.dot(r, r)
    out[c, k] = total
