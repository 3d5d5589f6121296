"""Backend discovery: every device is probed (a tiny kernel built and run) before anything picks it, an
unusable one is listed with its reason in one line and refused by name in one line, and the test
fixture turns unusable or absent backends into explicit skips."""

import io
import time

import numpy as np
import pytest
from conftest import BACKEND_ENTRIES, backend_params

import warp_biscale as wb
from warp_biscale import backend as backend_mod
from warp_biscale import device
from warp_biscale import progress

KEYS = {"name", "kind", "device", "type", "usable", "reason"}

# What PoCL 3.0's clang prints on a CPU newer than its LLVM (AMD Zen 5), as pyopencl raises it.
ZEN5_BUILD_LOG = ("clBuildProgram failed: BUILD_PROGRAM_FAILURE - clBuildProgram failed: BUILD_PROGRAM_FAILURE\n\n"
                  "Build on <pyopencl.Device 'pthread-AMD EPYC' on 'Portable Computing Language'>:\n\n"
                  "error: unknown target CPU 'generic'\nnote: valid target CPU values are: nocona, core2, ...")


def _usable_opencl():
    entries = [b for b in BACKEND_ENTRIES if b["kind"] == "opencl" and b["usable"]]
    if not entries:
        reasons = "; ".join(f"{b['name']}: {b['reason']}" for b in BACKEND_ENTRIES if b["kind"] == "opencl")
        pytest.skip(f"no usable OpenCL device here ({reasons})")
    return entries


def test_every_entry_says_its_state():
    assert BACKEND_ENTRIES, "backends() found nothing"
    for b in BACKEND_ENTRIES:
        assert set(b) == KEYS, b
        assert b["kind"] in ("warp", "opencl") and b["type"] in ("cpu", "gpu", None)
        if b["usable"]:
            assert b["reason"] == "" and b["device"]
            assert wb.get_backend(b["name"]).name == b["name"]
        else:
            assert b["reason"] and "\n" not in b["reason"]
    warp_cpu = [b for b in BACKEND_ENTRIES if b["name"] == "warp:cpu"]
    assert len(warp_cpu) == 1 and warp_cpu[0]["usable"], warp_cpu


def test_opencl_selection_by_device_type_vendor_and_index():
    usable = _usable_opencl()
    for kind in ("cpu", "gpu"):
        of_kind = [b for b in usable if b["type"] == kind]
        if of_kind:  # the first usable device of that type, whatever its name
            assert wb.get_backend(f"opencl:{kind}").name == of_kind[0]["name"]
            assert wb.get_backend(f"opencl:{kind}#0").name == of_kind[0]["name"]
        elif not [b for b in BACKEND_ENTRIES if b["kind"] == "opencl" and b["type"] == kind]:
            with pytest.raises(ValueError, match=rf"^no OpenCL {kind.upper()} device here; available: opencl:"):
                wb.get_backend(f"opencl:{kind}")
    first = usable[0]["name"].partition(":")[2]  # by a name: "#1" is the second match, counting from 0
    with pytest.raises(ValueError, match=r"no OpenCL device matches .*#9'; available: "):
        wb.get_backend(f"opencl:{first}#9")
    pocl = [b for b in usable if "PoCL" in b["device"]]
    if pocl:  # its platform's vendor is "The pocl project", its name "Portable Computing Language"
        assert wb.get_backend("opencl:pocl").name in [b["name"] for b in pocl]


@pytest.mark.parametrize("name", [b["name"] for b in BACKEND_ENTRIES if b["usable"]])
def test_probe_kernel_against_float64(name):
    """The probe passes on a usable backend because its kernel's output matches the float64 formula, and
    the check it is judged by rejects a wrong result."""
    assert device.probe_mismatch(device.probe_expected(device.PROBE_VALUES)) is None
    wrong = device.probe_expected(device.PROBE_VALUES).astype(np.float32)  # float32 rounding
    assert "wrong values" in device.probe_mismatch(wrong)
    assert "wrong values" in device.probe_mismatch(np.zeros(3))


def test_opencl_platform_that_cannot_build_is_unusable_with_the_fix(monkeypatch):
    from warp_biscale import opencl_backend as ocl

    _usable_opencl()

    def failing_build(ctx, stem, options):
        raise RuntimeError(ZEN5_BUILD_LOG)

    monkeypatch.setattr(ocl, "_PROBES", {})
    monkeypatch.setattr(ocl, "build_program", failing_build)
    entries = ocl.list_devices()
    cpu = [b for b in entries if b["type"] == "cpu"]
    assert cpu
    for b in cpu:
        assert not b["usable"] and "\n" not in b["reason"]
        assert "too old for this CPU" in b["reason"] and "apt-get install pocl-opencl-icd" in b["reason"]
        assert "unknown target CPU" in b["reason"]
        with pytest.raises(ValueError, match="is unusable: .*too old for this CPU") as err:
            ocl.OpenCLBackend(b["name"].partition(":")[2])
        assert "\n" not in str(err.value)
    if all(b["type"] == "cpu" for b in entries):
        with pytest.raises(ValueError, match="^no usable OpenCL device: ") as err:
            ocl.OpenCLBackend(None)
        assert "\n" not in str(err.value)


def test_opencl_build_that_works_is_usable(monkeypatch):
    from warp_biscale import opencl_backend as ocl

    names = {b["name"] for b in _usable_opencl()}
    monkeypatch.setattr(ocl, "_PROBES", {})  # probe again, for real
    again = {b["name"] for b in ocl.list_devices() if b["usable"]}
    assert names <= again
    assert ocl.OpenCLBackend(None).name in again  # None takes the first usable device


def test_shade_stage_register_cap_only_where_nvidia_options_are_taken():
    """The shade stage's build carries the register cap (device.SHADE_MAX_REGISTERS, the Warp kernel's too) only on a
    device that takes NVIDIA's compiler options, and no other stage does: another compiler would refuse the option.
    Every usable OpenCL device builds the shade stage with its backend's options (on an NVIDIA GPU, with the cap)."""
    from warp_biscale import opencl_backend as ocl
    from warp_biscale.device import SHADE_MAX_REGISTERS

    cap = f"-cl-nv-maxrregcount={SHADE_MAX_REGISTERS}"
    base = ["-cl-std=CL1.2"]
    assert cap in ocl.stage_options(base, "shade", nvidia_options=True)
    assert cap not in ocl.stage_options(base, "shade")
    assert all(cap not in ocl.stage_options(base, stem, nvidia_options=True)
               for stem in ("trace", "visibility", "asgfit", "litsphere"))
    for b in _usable_opencl():
        backend = wb.get_backend(b["name"])
        if "portable computing language" in backend._platform.name.lower():
            assert not backend._nvidia_options  # PoCL's compiler would refuse the option
        assert backend._build("shade") is not None  # with the backend's own options, the cap where it takes one


def test_unknown_build_failure_is_one_line(monkeypatch):
    from warp_biscale import opencl_backend as ocl

    _usable_opencl()
    monkeypatch.setattr(ocl, "_PROBES", {})
    monkeypatch.setattr(ocl, "build_program", lambda ctx, stem, options: (_ for _ in ()).throw(
        RuntimeError("clBuildProgram failed: BUILD_PROGRAM_FAILURE\n\nsomething else")))
    for b in ocl.list_devices():
        assert not b["usable"] and b["reason"] == "kernels do not build: clBuildProgram failed: BUILD_PROGRAM_FAILURE"


def test_auto_falls_back_to_opencl_when_warp_is_unusable(monkeypatch):
    _usable_opencl()
    real = backend_mod._make

    def no_warp(name):
        if name.startswith("warp"):
            raise ValueError("backend 'warp:cpu' is unusable here: (test)")
        return real(name)

    monkeypatch.setattr(backend_mod, "_make", no_warp)
    assert wb.get_backend("auto").name.startswith("opencl:")

    def nothing(name):
        raise ValueError(f"{name} is unusable here: (test)")

    monkeypatch.setattr(backend_mod, "_make", nothing)
    with pytest.raises(ValueError, match="^no usable backend here: warp is unusable here: .*; opencl is unusable"):
        wb.get_backend("auto")


def test_unusable_warp_device_is_refused_by_name(monkeypatch):
    from warp_biscale import warp_backend

    monkeypatch.setattr(warp_backend, "_PROBES", {"cpu": "Warp cannot build or run a kernel on cpu: (test)"})
    with pytest.raises(ValueError, match="^backend 'warp:cpu' is unusable here: Warp cannot build"):
        warp_backend.WarpBackend("cpu")
    assert not [b for b in warp_backend.list_devices() if b["name"] == "warp:cpu"][0]["usable"]


def test_fixture_skips_unusable_and_expected_absent_backends():
    entries = [
        {"name": "warp:cpu", "kind": "warp", "device": "CPU", "type": "cpu", "usable": True, "reason": ""},
        {"name": "warp:cuda", "kind": "warp", "device": None, "type": "gpu", "usable": False,
         "reason": "no NVIDIA CUDA driver found"},
        {"name": "opencl:pthread-X", "kind": "opencl", "device": "pthread-X (PoCL 3.0)", "type": "cpu",
         "usable": False, "reason": "too old for this CPU"},
        {"name": "opencl:pthread-haswell-X", "kind": "opencl", "device": "pthread-haswell-X (PoCL 3.1)",
         "type": "cpu", "usable": True, "reason": ""},
    ]
    params = {p.id: p for p in backend_params(entries)}
    assert set(params) == {"warp:cpu", "opencl:pthread-X", "opencl:pthread-haswell-X"}  # no CUDA on a CPU box
    assert not params["warp:cpu"].marks and not params["opencl:pthread-haswell-X"].marks
    (skip,) = params["opencl:pthread-X"].marks
    assert skip.name == "skip" and "too old for this CPU" in skip.kwargs["reason"]
    # no OpenCL at all, and a Warp that cannot start: both expected, both explicit skips
    none = backend_params([{"name": "warp:cpu", "kind": "warp", "device": None, "type": "cpu", "usable": False,
                            "reason": "Warp cannot start here: x"},
                           {"name": "opencl", "kind": "opencl", "device": None, "type": None, "usable": False,
                            "reason": "no OpenCL platform found"}])
    assert [p.id for p in none] == ["warp:cpu", "opencl"]
    assert all(p.marks[0].name == "skip" for p in none)


def test_compile_notice_once_and_not_when_quiet(monkeypatch):
    monkeypatch.setattr(progress, "COMPILE_NOTICE_DELAY", 0.01)
    monkeypatch.setattr(progress, "_COMPILE_NOTICE_SAID", False)
    out = io.StringIO()
    with progress.compile_notice(out):
        pass  # a cached build: no word
    assert out.getvalue() == ""
    with progress.compile_notice(out):
        time.sleep(0.2)
    with progress.compile_notice(out):
        time.sleep(0.2)
    assert out.getvalue() == "compiling kernels (first run only)…\n"
    monkeypatch.setattr(progress, "_COMPILE_NOTICE_SAID", False)
    monkeypatch.setattr(progress, "_QUIET", True)
    quiet = io.StringIO()
    with progress.compile_notice(quiet):
        time.sleep(0.2)
    assert quiet.getvalue() == ""


def test_a_backend_module_that_cannot_import_is_listed_not_raised(monkeypatch):
    """A broken toolkit install (here: the OpenCL module's import fails) is an unusable entry with its reason."""
    import sys

    monkeypatch.setitem(sys.modules, "warp_biscale.opencl_backend", None)  # makes its import raise ImportError
    entries = backend_mod.backends()
    (opencl,) = [b for b in entries if b["kind"] == "opencl"]
    assert not opencl["usable"] and opencl["reason"].startswith("OpenCL support cannot start here: ")
    assert any(b["name"] == "warp:cpu" and b["usable"] for b in entries)


def _pytest(require, *args):
    import os
    import subprocess
    import sys

    env = dict(os.environ, WARP_BISCALE_REQUIRE_BACKENDS=require)
    return subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *args],
                          capture_output=True, text=True, timeout=300, env=env,
                          cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def test_required_backend_that_is_missing_fails_the_run():
    """What CI relies on: a required backend that is not usable here stops the run with its reason."""
    r = _pytest("metal:gpu", "tests/test_backends.py", "-k", "every_entry")
    assert r.returncode != 0 and "required backend metal:gpu is not usable here (none found)" in r.stdout + r.stderr


def test_required_backend_that_ran_no_test_fails_the_run():
    r = _pytest("warp:cpu", "tests/test_backends.py", "-k", "every_entry")  # a test without the backend fixture
    assert r.returncode == 1 and "no test ran on a required backend (warp:cpu)" in r.stdout, r.stdout[-500:]
    r = _pytest("warp:cpu", "tests/test_backends.py::test_probe_kernel_against_float64")  # runs on warp:cpu
    assert r.returncode == 0, r.stdout[-500:]
