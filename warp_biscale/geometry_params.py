"""Parameter checks shared by the procedural tile generators.

Each check takes the generator's name and the parameter's name, so a bad value is refused before
any work in one line saying which call, which parameter and what was given.
"""

from __future__ import annotations

import math
from numbers import Integral, Real

import numpy as np

__all__ = ["WHITE", "real", "integer", "material_id", "rgb", "one_of", "format_params"]

WHITE = (1.0, 1.0, 1.0)


def real(fn, name, value, lo=None, hi=None, lo_open=False, hi_open=False) -> float:
    """A finite real in the given range, or a ValueError naming the parameter and its value."""
    if isinstance(value, bool) or not isinstance(value, Real):
        raise ValueError(f"{fn}: {name} must be a real number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{fn}: {name} must be finite, got {value!r}")
    bad_lo = lo is not None and (v < lo or (lo_open and v == lo))
    bad_hi = hi is not None and (v > hi or (hi_open and v == hi))
    if bad_lo or bad_hi:
        left = "-inf" if lo is None else f"{lo:g}"
        right = "inf" if hi is None else f"{hi:g}"
        interval = (
            f"{'(' if lo_open or lo is None else '['}{left}, {right}{')' if hi_open or hi is None else ']'}"
        )
        raise ValueError(f"{fn}: {name} must be in {interval}, got {value!r}")
    return v


def integer(fn, name, value, lo=None, hi=None) -> int:
    """An integer in [lo, hi] (booleans refused), or a ValueError naming the parameter and its value."""
    if isinstance(value, bool) or not isinstance(value, Integral):
        raise ValueError(f"{fn}: {name} must be an integer, got {value!r}")
    v = int(value)
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        bounds = f"in [{lo}, {hi}]" if lo is not None and hi is not None else f">= {lo}" if lo is not None \
            else f"<= {hi}"
        raise ValueError(f"{fn}: {name} must be an integer {bounds}, got {value!r}")
    return v


def material_id(fn, name, value, default=None) -> int:
    """A material id (an integer >= 0); None gives `default` where there is one."""
    if value is None and default is not None:
        return default
    if isinstance(value, bool) or not isinstance(value, Integral) or int(value) < 0:
        raise ValueError(f"{fn}: {name} must be a material id (an integer >= 0), got {value!r}")
    return int(value)


def rgb(fn, name, value, default=None) -> np.ndarray:
    """Three finite RGB weights >= 0 as a float64 array; None gives `default` where there is one."""
    if value is None and default is not None:
        return default
    try:
        c = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        c = None
    if c is None or c.shape != (3,) or not np.all(np.isfinite(c)) or (c < 0).any():
        raise ValueError(f"{fn}: {name} must be three finite RGB weights >= 0, got {value!r}")
    return c


def one_of(fn, name, value, options) -> str:
    """One of `options`; strings are lower-cased first, so "V" is "v"."""
    v = value.lower() if isinstance(value, str) else value
    if v not in options:
        raise ValueError(f"{fn}: {name} must be one of {', '.join(repr(o) for o in options)}, got {value!r}")
    return v


def format_params(**kw) -> str:
    """Parameters as `name=value, ...` for error messages (floats in %g)."""
    return ", ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v!r}" for k, v in kw.items())
