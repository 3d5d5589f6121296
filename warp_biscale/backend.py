"""One protocol for every compute backend, and selection by name.

A backend implements each stage primitive on its device and hands back the data model
(`Facets`, `Visibility`, numpy arrays). The pipeline calls only these methods and never asks which
kind of backend it holds. Names:

``"warp"`` (Warp, CUDA if present else CPU), ``"warp:cpu"``, ``"warp:cuda"`` / ``"warp:cuda:N"``,
``"opencl"`` (first OpenCL device, GPUs first), ``"opencl:<substring>"`` (first device whose
platform or device name contains the substring, case-insensitive), ``"auto"`` (Warp on CUDA if
present, else Warp CPU).
"""

from __future__ import annotations

import functools
from typing import Protocol, runtime_checkable

import numpy as np

from .model import Facets, Visibility

__all__ = ["Backend", "get_backend", "backends", "chunking"]


@runtime_checkable
class Backend(Protocol):
    name: str  # the selection name that reproduces this backend, e.g. "warp:cpu"
    device: str  # what it runs on, in words

    def synchronize(self) -> None:
        """Block until all queued work has finished (for timing)."""

    def sample_facets(self, tile, count: int, seed: int) -> Facets:
        """`count` area-weighted stratified facets of `tile` (reference.sample_facets)."""

    def visibility(self, tile, facets: Facets, directions: np.ndarray, brute_force: bool = False) -> Visibility:
        """V_s(ω) bits for (D, 3) unit directions (reference.visibility); brute_force tests every
        triangle instead of walking the BVH (for testing the BVH)."""

    def visible_area(self, facets: Facets, vis: Visibility) -> np.ndarray:
        """(D,) float32 a_v(ω) (reference.visible_area)."""

    def effective_brdf(self, facets: Facets, vis: Visibility, kinds: np.ndarray, params: np.ndarray,
                       pair_i: np.ndarray, pair_o: np.ndarray, a_v: np.ndarray) -> np.ndarray:
        """(P, 3) float32 f̄ for direction index pairs into vis.directions (reference.effective_brdf)."""


def chunking(n_words: int, n_outputs: int, threads: int) -> tuple[int, int]:
    """Split n_words facet words into chunks so that n_outputs × chunks ≈ threads.

    → (chunks, words_per_chunk). A serial device wants one chunk; a GPU wants enough threads to fill.
    """
    chunks = int(np.clip(-(-threads // max(n_outputs, 1)), 1, max(n_words, 1)))
    words = -(-n_words // chunks)
    chunks = max(1, -(-n_words // words))
    return chunks, words


@functools.lru_cache(maxsize=None)
def _make(name: str) -> Backend:
    kind, _, rest = name.partition(":")
    if kind == "warp":
        from .warp_backend import WarpBackend

        return WarpBackend(rest or None)
    if kind == "opencl":
        from .opencl_backend import OpenCLBackend

        return OpenCLBackend(rest or None)
    raise ValueError(f"unknown backend {name!r}; use 'auto', 'warp', 'warp:cpu', 'warp:cuda', 'opencl' or "
                     "'opencl:<platform or device substring>'")


def get_backend(backend="auto") -> Backend:
    """A backend by name (cached: the same name returns the same object), or pass one through."""
    if isinstance(backend, Backend) and not isinstance(backend, str):
        return backend
    if not isinstance(backend, str):
        raise ValueError(f"backend must be a name or a Backend, got {backend!r}")
    name = backend.strip().lower() or "auto"
    if name == "auto":
        name = "warp"
    return _make(name)


def backends() -> list[dict]:
    """What is present: a list of {name, kind, device} for every backend that can run here."""
    found = []
    try:
        import warp as wp

        from .warp_backend import init_warp

        init_warp()
        for dev in wp.get_devices():
            found.append({"name": f"warp:{dev.alias}", "kind": "warp", "device": dev.name})
    except Exception as exc:  # an unusable Warp install is reported, not fatal
        found.append({"name": "warp", "kind": "warp", "device": None, "error": str(exc)})
    try:
        from .opencl_backend import list_devices

        for entry in list_devices():
            found.append({"name": entry["name"], "kind": "opencl", "device": entry["device"]})
    except Exception as exc:
        found.append({"name": "opencl", "kind": "opencl", "device": None, "error": str(exc)})
    return found
