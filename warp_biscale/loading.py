"""Reading back any saved warp_biscale object (`wb.load`): a ground-truth table, a baked effective
BRDF (SG, matrix or ASG method), told apart by the header every saved file carries (see `io`), or a
lit-sphere folder."""

from __future__ import annotations

import json
import os

import numpy as np

from .asg_bake import ASGBRDF
from .effective import EffectiveBRDF
from .io import read_npz
from .litsphere import LitSphere
from .matrix import MatrixBRDF
from .measured import MeasuredBRDF
from .truth import GroundTruth

__all__ = ["load"]


def head_version(path):
    """The version field of a file's header, so that `load` can hand a newer file to its class,
    which then refuses it with its own versions in the message."""
    try:
        with np.load(os.fspath(path), allow_pickle=False) as z:
            return json.loads(str(z["header"])).get("version", 1)
    except Exception:
        return 1


def load(path):
    """Load any saved warp_biscale object: a ground-truth table, a baked effective BRDF (an
    `EffectiveBRDF`, a `MatrixBRDF` of bake(..., method="matrix") or an `ASGBRDF` of method="asg"), a
    lit-sphere folder (`LitSphere.save`'s), or a measured BRDF in MERL's format (a `.binary`: `MeasuredBRDF.load`)."""
    if os.path.isdir(os.fspath(path)):
        return LitSphere.load(path)  # (its own one-line error for a folder that is not one)
    if os.fspath(path).lower().endswith(".binary"):
        return MeasuredBRDF.load(path)

    classes = {"warp_biscale.ground_truth": GroundTruth, "warp_biscale.effective_brdf": EffectiveBRDF,
               f"warp_biscale.{MatrixBRDF.FORMAT}": MatrixBRDF, f"warp_biscale.{ASGBRDF.FORMAT}": ASGBRDF}
    head, _ = read_npz(path, versions=(head_version(path),))
    fmt = head["format"]
    if fmt in classes:
        return classes[fmt].load(path)
    raise ValueError(f"{path}: no loader for {fmt!r}")
