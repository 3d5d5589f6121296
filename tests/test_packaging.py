"""kernels/ and cl/ are installed inside the package (docs/design.md §2), in a wheel and in this install."""

import importlib
import importlib.util
import subprocess
import sys
import zipfile
from pathlib import Path


ROOT = Path(__file__).resolve().parents[1]


def test_installed_package_has_kernels_and_cl():
    kernels = importlib.import_module("warp_biscale.kernels.visibility")
    assert hasattr(kernels, "visibility_rays")
    from warp_biscale import cl

    src = cl.source("visibility")
    assert "__kernel" in src and "visibility_rays" in src
    # Nothing generic installed at the top level (a `kernels` found in this checkout, when the
    # current directory is on sys.path, is not an installed one).
    for generic in ("kernels", "cl"):
        spec = importlib.util.find_spec(generic)
        assert spec is None or Path(spec.origin).resolve().is_relative_to(ROOT), spec.origin


def test_wheel_contains_kernels_and_cl(tmp_path):
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
                        "-w", str(tmp_path), str(ROOT)], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    wheel = next(tmp_path.glob("warp_biscale-*.whl"))
    names = set(zipfile.ZipFile(wheel).namelist())
    for stem in ("facets", "visibility", "truth"):
        assert f"warp_biscale/kernels/{stem}.py" in names
        assert f"warp_biscale/cl/{stem}.cl" in names
    assert "warp_biscale/cl/common.cl" in names
    assert not any(n.startswith(("kernels/", "cl/")) for n in names)
