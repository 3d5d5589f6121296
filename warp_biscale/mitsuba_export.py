"""Mitsuba 3 export of a baked effective BRDF (docs/mitsuba.md).

    mat.export_mitsuba("out")                # or: warp-biscale export m.wbm --to mitsuba -o out
    python out/render.py                     # Mitsuba 3's path tracer → out/render.exr

`export` writes a folder: `material.wbm` (a copy of the material), `scene.xml` (a sphere of it under a
constant environment and a directional light, seen by a perspective camera) and `render.py` (registers the
plugin, renders the scene). Rendering needs Mitsuba 3 and warp_biscale; writing the folder needs neither
Mitsuba nor a device.

The plugin (`register()`: BSDF type "warp_biscale", its string property `filename` the .wbm, resolved as
Mitsuba resolves file names, i.e. beside the scene file; optional `method`, "sg" or "sg-exact", default the
bake's) evaluates f̄ exactly as `EffectiveBRDF.eval` does (docs/design.md §5.4: the amplitudes interpolated
bilinearly in the square domain of each direction, μ/cos θi interpolated and cos θi multiplied back), in
Dr.Jit, so that Mitsuba's JIT variants trace it into their kernels (RGB variants: llvm_ad_rgb, cuda_ad_rgb).
Mitsuba's BSDF value includes the cosine of the light direction, as f̄ does (§4.6), so f̄ is returned as it is:
Mitsuba's `wo` (towards the light) is our ωi, its `si.wi` (towards the viewer) our ωo, both in the shading frame
(s along ∂p/∂u, t = n × s), our tile frame (t, b, n) with its tangent along the surface's u direction. Values are
float32 (Mitsuba's); f̄ is 0 below either horizon and never NaN, inf or negative, nor is a sample's weight.
Dr.Jit 1.5's LLVM backend needs a newer LLVM than Debian 12's 14/15, on which it aborts compiling any kernel
(Mitsuba's own too): `apt-get install libllvm19` (docs/mitsuba.md).

Sampling is a mixture: with probability p_d the cosine lobe; else one specular lobe q = (small-scale
material m, NDF lobe j), whose half vector h is drawn from the von Mises–Fisher lobe of the SG that f̄'s
specular term has in h (axis ξ_j, sharpness η_jη_s/(η_j + η_s), Iwasaki Eq. 14), and ω = 2(ωo·h)h − ωo.
The shares depend on the material alone (kd against ks, each lobe's mean energy in the tables, a floor
for every lobe), and the density is the mixture's exact one: [p_h(h) + p_h(−h)]/(4 ωo·h) for a lobe (h and
−h reflect to the same ω), (n·ω)/π for the cosine; directions below the horizon carry no weight.
"""

from __future__ import annotations

import copy
import os
import shutil
import zipfile

import numpy as np

from . import sg
from .brdf import BlinnPhong, CookTorrance, Lambert, Ward
from .directions import grid
from .effective import EXPORTERS, METHODS, EffectiveBRDF
from .io import atomic_path, check_output

__all__ = ["export", "register", "PLUGIN", "FILES", "VARIANTS"]

PLUGIN = "warp_biscale"  # the BSDF type name scene files use
FILES = {"material": "material.wbm", "scene": "scene.xml", "script": "render.py"}
VARIANTS = ("llvm_ad_rgb", "cuda_ad_rgb")  # the plugin is Dr.Jit code: JIT variants, RGB colour
MIN_SHARE = 0.1  # the cosine lobe's least and greatest share of the samples when both terms are present
LOBE_FLOOR = 0.05  # share of the specular samples spread evenly over the lobes, so none is left unsampled
_SPECULAR = (BlinnPhong, CookTorrance, Ward)


def _check_material(mat, what: str) -> EffectiveBRDF:
    if not isinstance(mat, EffectiveBRDF):
        raise ValueError(f"{what} must be an EffectiveBRDF (a baked material, wb.bake or wb.load), "
                         f"got {type(mat).__name__}")
    for i, b in enumerate(mat.materials):
        if type(b) not in (Lambert,) + _SPECULAR:
            raise ValueError(f"{what}: small-scale material {i} is a {type(b).__name__}; the Mitsuba plugin evaluates "
                             "Lambert, BlinnPhong, CookTorrance and Ward")
    return mat


# ---------------------------------------------------------------------------------------------------
# the export
# ---------------------------------------------------------------------------------------------------


def export(mat, path) -> dict:
    """Write the Mitsuba 3 files of baked material `mat` into folder `path` (made if missing; files of the
    same names an earlier export wrote are replaced, each atomically; other files of those names are a
    ValueError, before anything is written) → {"material", "scene", "script": their paths}. A failed write (a
    full disk) is an OSError naming the file, and removes the folder where the export made it."""
    _check_material(mat, "export_mitsuba: the material")
    folder = os.fspath(path)
    if os.path.exists(folder) and not os.path.isdir(folder):
        raise ValueError(f"Mitsuba export folder {folder!r} is a file, not a folder")
    check_output(os.path.join(folder, FILES["scene"]), what="Mitsuba export")
    out = {key: os.path.join(folder, name) for key, name in FILES.items()}
    texts = {"scene": SCENE_XML.format(plugin=PLUGIN, material=FILES["material"]),
             "script": RENDER_SCRIPT.format(scene=FILES["scene"])}
    for key, name in out.items():  # an earlier export's files are replaced; a user's own are not
        if os.path.isfile(name) and not _written_by_export(name, texts.get(key)):
            raise ValueError(f"Mitsuba export: {name!r} exists and was not written by an export; give another "
                             "folder or move the file")
    made = _first_missing(folder)  # the folder the export makes, if any: a failed export removes it again
    try:
        copy.copy(mat).save(out["material"])  # a copy: saving sets `path`, which must stay the caller's file
        for key, text in texts.items():
            with atomic_path(out[key]) as tmp:
                with open(tmp, "w", encoding="utf-8") as fh:
                    fh.write(text)
    except BaseException:
        if made is not None:  # (all in it is this export's: a full disk leaves no empty folder behind)
            shutil.rmtree(made, ignore_errors=True)
        raise
    return out


def _first_missing(folder) -> str | None:
    """The outermost folder of `folder`'s path that does not exist yet (the one whose making makes the rest), or
    None where `folder` exists."""
    folder = os.path.abspath(folder)
    missing = None
    while not os.path.exists(folder):
        missing, folder = folder, os.path.dirname(folder)
    return missing


def _written_by_export(path, text) -> bool:
    """Whether the file at `path` is one an export writes: the script or scene beginning with `text`'s
    first line, or (text None) a saved material (an npz, a zip)."""
    if text is None:
        return zipfile.is_zipfile(path)
    first = text.split("\n", 1)[0]
    with open(path, encoding="utf-8", errors="replace") as fh:
        return fh.read(len(first)) == first


SCENE_XML = """<!-- A sphere of a baked warp_biscale material. The BSDF type "{plugin}" is a Python plugin: register it
     before loading this file (render.py beside it does: warp_biscale.mitsuba_export.register()). -->
<scene version="3.0.0">
    <default name="spp" value="256"/>
    <default name="width" value="384"/>
    <default name="height" value="288"/>

    <!-- a lone convex sphere needs 2 (one bounce); more for objects that light each other -->
    <integrator type="path">
        <integer name="max_depth" value="8"/>
    </integrator>

    <sensor type="perspective">
        <string name="fov_axis" value="y"/>
        <float name="fov" value="30"/>
        <transform name="to_world">
            <lookat origin="0, 0, 4.5" target="0, 0, 0" up="0, 1, 0"/>
        </transform>
        <sampler type="independent">
            <integer name="sample_count" value="$spp"/>
        </sampler>
        <film type="hdrfilm">
            <integer name="width" value="$width"/>
            <integer name="height" value="$height"/>
            <rfilter type="box"/>
        </film>
    </sensor>

    <bsdf type="{plugin}" id="material">
        <!-- resolved beside this file; "method" (sg or sg-exact) may override the bake's -->
        <string name="filename" value="{material}"/>
    </bsdf>

    <!-- the tile's x axis follows the surface's u direction: rotated so, as on warp_biscale's Mesh.sphere,
         u runs around +y (eastwards) -->
    <shape type="sphere">
        <transform name="to_world">
            <rotate x="1" angle="-90"/>
        </transform>
        <ref id="material"/>
    </shape>

    <emitter type="constant">
        <rgb name="radiance" value="0.4"/>
    </emitter>
    <emitter type="directional">
        <vector name="direction" x="0.4" y="-0.7" z="-0.6"/>
        <rgb name="irradiance" value="2.0"/>
    </emitter>
</scene>
"""

RENDER_SCRIPT = '''"""Render {scene} (a sphere of a baked warp_biscale material) with Mitsuba 3's path tracer.

    python render.py [--spp N] [--variant llvm_ad_rgb] [-o render.exr]

Needs Mitsuba 3 (pip install mitsuba) and warp_biscale, whose BSDF plugin evaluates and samples the material
(registered below before the scene is loaded). Written by warp_biscale's Mitsuba export (docs/mitsuba.md).
"""

import argparse
import os

import mitsuba as mi


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spp", type=int, default=256, help="samples per pixel (default 256)")
    parser.add_argument("--variant", default="llvm_ad_rgb", help="llvm_ad_rgb (CPU, default) or cuda_ad_rgb")
    parser.add_argument("-o", "--output", default=os.path.join(here, "render.exr"),
                        help="image to write (.exr linear, .png tone-mapped; default render.exr here)")
    args = parser.parse_args()
    try:  # (a variant Mitsuba lacks, or one the plugin does not run in: one line)
        mi.set_variant(args.variant)
        from warp_biscale.mitsuba_export import register

        register()
    except (ImportError, AttributeError, ValueError) as exc:
        raise SystemExit(f"error: --variant {{args.variant!r}}: {{exc}}")
    scene = mi.load_file(os.path.join(here, "{scene}"), spp=args.spp)
    mi.util.write_bitmap(args.output, mi.render(scene))
    print(f"wrote {{args.output}}")


if __name__ == "__main__":
    main()
'''


# ---------------------------------------------------------------------------------------------------
# what the plugin reads, on the host (float64 numpy)
# ---------------------------------------------------------------------------------------------------


def plugin_tables(mat: EffectiveBRDF, method: str | None = None) -> dict:
    """The material as the plugin evaluates it, float64:

    k; diffuse (K², K², 3): Σ_m kd_m/π Σ_j (μ_mj/cos θi)·∫G_j on the grid (Eq. 9 without cos θi; linear in μ, so
    interpolating it is interpolating the μ); specular (K², K², Q, 3): μ_mj/cos θi of the Q lobes q = (m, j) of the
    materials with a specular term; lobes: per q a dict (material m, its BRDF, axis ξ_j, η_j, η_s, the "sg" closure's
    sharpness and amplitude); p_diffuse and weights (Q,): the sampling shares (module docstring)."""
    method = mat.method if method is None else method
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    per_cos = mat.amplitudes.astype(np.float64) / grid(mat.directions)[:, 2][None, :, None, None, None]
    integrals = sg.integral(mat.lobes.sharpness)
    energy = np.einsum("miojc,j->mj", per_cos, integrals) / (per_cos.shape[1] ** 2 * 3)  # a lobe's mean energy
    diffuse = np.zeros(per_cos.shape[1:3] + (3,))
    lobes, columns, w_spec, w_diffuse = [], [], [], 0.0
    for m, b in enumerate(mat.materials):
        kd = np.asarray(b.albedo if isinstance(b, Lambert) else b.kd, np.float64)
        diffuse += np.einsum("iojc,j->ioc", per_cos[m], integrals) * kd / np.pi
        w_diffuse += float(energy[m].sum() * kd.mean())
        ks = np.asarray(b.packed()[3:6], np.float64)
        if not isinstance(b, _SPECULAR) or not ks.any():
            continue  # no specular term (Lambert, ks = 0), as EffectiveBRDF.eval skips it
        eta_s = float(sg.specular_lobe(b, [[0.0, 0.0, 1.0]], [[0.0, 0.0, 1.0]])[0])
        for j, (axis, eta) in enumerate(zip(mat.lobes.axes, mat.lobes.sharpness)):
            eta_c, amp_c = sg.convolve(eta, 1.0, eta_s, 1.0)
            lobes.append({"material": m, "brdf": b, "ks": ks, "axis": np.asarray(axis, np.float64), "eta": float(eta),
                          "eta_s": eta_s, "eta_c": float(eta_c), "amp_c": float(amp_c)})
            columns.append(per_cos[m, :, :, j])
            w_spec.append(float(energy[m, j] * ks.mean()))
    specular = np.stack(columns, 2) if columns else np.zeros(per_cos.shape[1:3] + (0, 3))
    w_spec = np.asarray(w_spec)
    total = w_spec.sum()
    p_diffuse = 1.0  # no specular lobe: the cosine lobe alone
    if lobes:
        share = w_diffuse / (w_diffuse + total) if w_diffuse + total > 0 else 0.5
        p_diffuse = float(np.clip(share, MIN_SHARE, 1 - MIN_SHARE))
    even = np.full(len(lobes), 1.0 / max(len(lobes), 1))
    weights = (1 - LOBE_FLOOR) * w_spec / total + LOBE_FLOOR * even if total > 0 else even
    return {"k": mat.directions, "method": method, "diffuse": diffuse, "specular": specular, "lobes": lobes,
            "p_diffuse": p_diffuse, "weights": weights}


# ---------------------------------------------------------------------------------------------------
# the plugin (Dr.Jit; the class is made per Mitsuba variant, which fixes mi.BSDF and the array types)
# ---------------------------------------------------------------------------------------------------

_CLASSES: dict = {}


def register() -> type:
    """Register BSDF type "warp_biscale" in Mitsuba's current variant (an RGB JIT one, `VARIANTS`; set it first
    with mi.set_variant) → the plugin class. Scene files and dicts can then use it."""
    try:
        import mitsuba as mi
    except ImportError:
        raise ValueError("the Mitsuba plugin needs Mitsuba 3 (pip install mitsuba)") from None
    variant = mi.variant()
    if variant is None or not (mi.is_rgb and variant.split("_")[0] in ("llvm", "cuda")):
        # (no advice on how to change it: render.py's users choose it by its --variant option, not by a call)
        raise ValueError(f"the warp_biscale Mitsuba plugin runs in an RGB JIT variant ({', '.join(VARIANTS)}), "
                         f"not in {variant!r}")
    if variant not in _CLASSES:
        _CLASSES[variant] = _bsdf_class(mi)
    cls = _CLASSES[variant]
    mi.register_bsdf(PLUGIN, lambda props: cls(props))
    return cls


def _bsdf_class(mi):
    import drjit as dr

    Float, UInt32, Color3f, Vector3f = mi.Float, mi.UInt32, mi.Color3f, mi.Vector3f
    quarter = np.pi / 4

    def const(cls, v):
        """A constant array of numpy float64 values (Dr.Jit takes Python floats)."""
        return cls(*(float(x) for x in v))

    def one_minus_cos(a, b):
        """1 − a·b of unit vectors as ‖a − b‖²/2 (sg.one_minus_cos: exact near a = b, in float32 too)."""
        return 0.5 * dr.squared_norm(a - b)

    def expm1(x):
        """e^x − 1 without cancellation near 0 (Kahan's trick: the rounding of e^x cancels in (u − 1)/log u)."""
        u = dr.exp(x)
        return dr.select(u == 1, x, dr.select(u - 1 == -1, -1.0, (u - 1) * x / dr.log(u)))

    def log1p(x):
        """log(1 + x) without cancellation near 0 (the same trick)."""
        u = 1 + x
        return dr.select(u == 1, x, dr.log(u) * x / (u - 1))

    def corners(w, k):
        """directions.bilinear_corners: 4 grid indices and weights of directions w (z clamped to [0, 1])."""
        z = dr.clip(w.z, 0.0, 1.0)
        r = dr.sqrt((w.x * w.x + w.y * w.y) / (1 + z))  # √(1 − z) of a unit vector, without cancellation at z → 1
        phi = dr.atan2(w.y, w.x)
        phi = dr.select(phi < -quarter, phi + 2 * np.pi, phi)  # [−π/4, 7π/4): the concentric map's 4 wedges
        m0, m1, m2 = phi < quarter, phi < 3 * quarter, phi < 5 * quarter
        a = dr.select(m0, r, dr.select(m1, -(phi - np.pi / 2) * r / quarter,
                                       dr.select(m2, -r, (phi - 3 * np.pi / 2) * r / quarter)))
        b = dr.select(m0, phi * r / quarter, dr.select(m1, r, dr.select(m2, -(phi - np.pi) * r / quarter, -r)))
        cells = []
        for s in (a, b):
            x = dr.clip((s + 1) / 2 * k - 0.5, 0.0, k - 1.0)
            x0 = dr.minimum(dr.floor(x), k - 1.0)
            cells.append((UInt32(x0), UInt32(dr.minimum(x0 + 1, k - 1.0)), x - x0))
        (c0, c1, tx), (r0, r1, ty) = cells
        return ((r0 * k + c0, r0 * k + c1, r1 * k + c0, r1 * k + c1),
                ((1 - tx) * (1 - ty), tx * (1 - ty), (1 - tx) * ty, tx * ty))

    def one_minus_exp_over(d):
        """(1 − e^{−2d})/d, 2 at d = 0."""
        return dr.select(d > 1e-20, -expm1(-2 * d) / dr.maximum(d, 1e-20), 2.0)

    class EffectiveBSDF(mi.BSDF):
        """A baked warp_biscale material (EffectiveBRDF) as a Mitsuba BSDF: module docstring. The lobes are looped
        over symbolically (dr.while_loop), so the kernel's size, and its compile time, do not grow with J."""

        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            if "filename" not in props:
                raise ValueError(f'BSDF "{PLUGIN}" needs a string property "filename" (the .wbm material file)')
            self.filename = str(mi.file_resolver().resolve(props["filename"]))
            mat = _check_material(EffectiveBRDF.load(self.filename), self.filename)
            t = plugin_tables(mat, props["method"] if "method" in props else None)
            self.method, self.k, lobes = t["method"], t["k"], t["lobes"]
            self.q, self.p_diffuse = len(lobes), t["p_diffuse"]
            self.diffuse = Float(t["diffuse"].astype(np.float32).ravel())
            self.specular = Float(t["specular"].astype(np.float32).ravel())
            # per lobe q, gathered by q in the loops (lobes of one material are consecutive)
            self.axes = Float(np.array([lobe["axis"] for lobe in lobes], np.float32).ravel())
            for key in ("eta", "eta_c", "amp_c"):
                setattr(self, key, Float(np.array([lobe[key] for lobe in lobes], np.float32)))
            eta_c = np.array([lobe["eta_c"] for lobe in lobes])
            self.vmf_norm = Float((t["weights"] / sg.integral(eta_c)).astype(np.float32))  # share / ∫G
            self.expm1 = Float(np.expm1(-2 * eta_c).astype(np.float32))  # for the vMF's inverse CDF
            self.cdf = Float(np.cumsum(t["weights"]).astype(np.float32))
            # per material with a specular term: (its first lobe, one past its last, its BRDF, ks, η_s)
            self.groups = []
            for q, lobe in enumerate(lobes):
                if q == 0 or lobe["material"] != lobes[q - 1]["material"]:
                    self.groups.append([q, q + 1, lobe["brdf"], lobe["ks"], lobe["eta_s"]])
                self.groups[-1][1] = q + 1
            flags = mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide
            self.m_components = [flags]
            self.m_flags = flags

        # ---------------------------------------------------------------- f̄
        def value(self, wi, wo, active=True):
            """f̄(ωi, ωo) (cos θi included), ωi towards the light, ωo towards the viewer, local; 0 below the
            horizon, never NaN, inf or negative: EffectiveBRDF.eval in float32."""
            n = self.k * self.k
            ii, iw = corners(wi, self.k)
            oo, ow = corners(wo, self.k)
            pairs = [ii[a] * n + oo[b] for a in range(4) for b in range(4)]  # the 16 corner pairs of (ωi, ωo)
            weights = [iw[a] * ow[b] for a in range(4) for b in range(4)]
            out = Color3f(0.0)
            for p, w in zip(pairs, weights):
                out += w * dr.gather(Color3f, self.diffuse, p, active)
            s = wi + wo
            h = dr.select(dr.squared_norm(s) > 0, dr.normalize(s), Vector3f(0, 0, 1))
            cos_d = dr.clip(dr.dot(h, wi), 1e-6, 1.0)
            for first, last, brdf, ks, eta_s in self.groups:

                def body(q, acc, eta_s=eta_s):
                    mu = Color3f(0.0)  # μ_mj/cos θi, interpolated
                    for p, w in zip(pairs, weights):
                        mu += w * dr.gather(Color3f, self.specular, p * self.q + q, active)
                    axis = dr.gather(Vector3f, self.axes, q)
                    if self.method == "sg":  # Eq. 15: the closure's SG in h
                        lobe_h = dr.gather(Float, self.amp_c, q) * dr.exp(-dr.gather(Float, self.eta_c, q)
                                                                           * one_minus_cos(h, axis))
                    else:  # Eq. 10: sg.inner_product(h, η_s, 1, ξ_j, η_j, 1)
                        eta = dr.gather(Float, self.eta, q)
                        d = dr.sqrt(dr.maximum((eta_s - eta) ** 2 + eta_s * eta * dr.squared_norm(h + axis), 0.0))
                        gap = 2 * eta_s * eta * one_minus_cos(h, axis) / (eta_s + eta + d)
                        lobe_h = 2 * np.pi * dr.exp(-gap) * one_minus_exp_over(d)
                    return q + 1, acc + mu * lobe_h

                _, lobes_sum = dr.while_loop(state=(UInt32(first), Color3f(0.0)),
                                             cond=lambda q, acc, last=last: q < last, body=body)
                out += self.scale(brdf, ks, cos_d) * lobes_sum
            out *= dr.maximum(wi.z, 0.0)
            ok = active & (wi.z > 0) & (wo.z > 0) & dr.all(dr.isfinite(out))
            return dr.select(ok, dr.maximum(out, 0.0), 0.0)

        @staticmethod
        def scale(brdf, ks, cos_d):
            """M_m of sg.specular_lobe (RGB): Blinn–Phong's constant, Cook–Torrance's and Ward's in cos θd."""
            if isinstance(brdf, BlinnPhong):
                return const(Color3f, ks * (brdf.exponent + 2) / (2 * np.pi))
            if isinstance(brdf, CookTorrance):
                fres = brdf.f0 + (1 - brdf.f0) * (1 - cos_d) ** 5
                return const(Color3f, ks) * (fres / (np.pi * cos_d * cos_d))
            return const(Color3f, ks) / (4 * np.pi * brdf.alpha**2 * cos_d)

        # ---------------------------------------------------------------- sampling
        def density(self, wi, wo, active=True):
            """The sampling density of ωi given ωo (per steradian; 0 below the horizon)."""
            p = self.p_diffuse * dr.maximum(wi.z, 0.0) / np.pi
            if self.q:
                h = dr.normalize(wi + wo)

                def body(q, acc):
                    axis, eta = dr.gather(Vector3f, self.axes, q), dr.gather(Float, self.eta_c, q)
                    both = dr.exp(-eta * one_minus_cos(h, axis)) + dr.exp(-eta * one_minus_cos(-h, axis))
                    return q + 1, acc + dr.gather(Float, self.vmf_norm, q) * both

                _, lobes = dr.while_loop(state=(UInt32(0), Float(0.0)), cond=lambda q, acc: q < self.q, body=body)
                p += (1 - self.p_diffuse) * lobes / (4 * dr.maximum(dr.dot(wo, h), 1e-12))
            return dr.select(active & (wi.z > 0) & (wo.z > 0) & dr.isfinite(p), p, 0.0)

        def draw(self, wo, sample1, sample2):
            """ωi from the mixture: the cosine lobe if sample1 < p_d, else lobe q picked by sample1, h ~ its vMF."""
            wi = mi.warp.square_to_cosine_hemisphere(sample2)
            if not self.q:
                return wi
            u = (sample1 - self.p_diffuse) / (1 - self.p_diffuse)
            q = dr.binary_search(0, self.q - 1, lambda i: dr.gather(Float, self.cdf, i) <= u)  # first cdf past u
            axis, eta = dr.gather(Vector3f, self.axes, q), dr.gather(Float, self.eta_c, q)
            # sample_vmf: 1 − cos θ = −log1p(u·expm1(−2η))/η, exact for a uniform (η → 0) and a sharp lobe
            one_minus = dr.clip(-log1p((1 - sample2.x) * dr.gather(Float, self.expm1, q)) / eta, 0.0, 2.0)
            sin_t = dr.sqrt(one_minus * (2 - one_minus))
            phi = 2 * np.pi * sample2.y
            h = mi.Frame3f(axis).to_world(Vector3f(sin_t * dr.cos(phi), sin_t * dr.sin(phi), 1 - one_minus))
            return dr.select(sample1 < self.p_diffuse, wi, 2 * dr.dot(wo, h) * h - wo)

        # ---------------------------------------------------------------- Mitsuba's interface
        @staticmethod
        def enabled(ctx, active):
            """`active`, and False for a context that leaves out glossy reflection (the one component)."""
            return active & ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 0)

        def sample(self, ctx, si, sample1, sample2, active=True):
            active = self.enabled(ctx, active)
            wi = dr.normalize(self.draw(si.wi, sample1, sample2))
            value, pdf = self.value(wi, si.wi, active), self.density(wi, si.wi, active)
            bs = mi.BSDFSample3f()
            bs.wo, bs.pdf, bs.eta = wi, pdf, 1.0
            bs.sampled_type = UInt32(+mi.BSDFFlags.GlossyReflection)
            bs.sampled_component = UInt32(0)
            weight = value / dr.maximum(pdf, 1e-30)
            return bs, dr.select((pdf > 0) & dr.all(dr.isfinite(weight)), weight, 0.0)

        def eval(self, ctx, si, wo, active=True):
            return self.value(wo, si.wi, self.enabled(ctx, active))

        def pdf(self, ctx, si, wo, active=True):
            return self.density(wo, si.wi, self.enabled(ctx, active))

        def eval_pdf(self, ctx, si, wo, active=True):
            active = self.enabled(ctx, active)
            return self.value(wo, si.wi, active), self.density(wo, si.wi, active)

        def to_string(self):
            return (f"EffectiveBSDF[filename={self.filename!r}, method={self.method!r}, K={self.k}, "
                    f"specular lobes={self.q}]")

    return EffectiveBSDF


EXPORTERS["mitsuba"] = export  # EffectiveBRDF.export_mitsuba
