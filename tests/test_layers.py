"""docs/design.md §2's module layers hold in the code: every module of warp_biscale is in one layer, and no
import (top-level or inside a function) reaches a later layer."""

import ast
import os
import re

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PACKAGE = os.path.join(ROOT, "warp_biscale")


def _documented_layers() -> list[set]:
    text = open(os.path.join(ROOT, "docs", "design.md"), encoding="utf-8").read()
    start = text.index("`warp_biscale/` holds everything that is not a kernel, in layers")
    block = text[start:text.index("`reference` (the float64 oracle)", start)]
    items = re.split(r"^\d\. ", block, flags=re.M)[1:]
    return [set(re.findall(r"`([a-z_]+)`", item)) for item in items]


def _imports(path) -> set:
    found = set()
    for node in ast.walk(ast.parse(open(path, encoding="utf-8").read())):
        if isinstance(node, ast.ImportFrom) and node.level == 1:
            found.update([node.module.split(".")[0]] if node.module else [a.name for a in node.names])
    return found


def test_every_module_is_in_one_documented_layer_and_imports_none_after_it():
    layers = _documented_layers()
    assert len(layers) == 5, layers
    modules = {f[:-3] for f in os.listdir(PACKAGE) if f.endswith(".py") and f not in ("__init__.py", "__main__.py")}
    where = {}
    for i, layer in enumerate(layers):
        for name in layer & modules:
            assert name not in where, f"{name} is in layers {where[name] + 1} and {i + 1}"
            where[name] = i
    assert modules <= set(where), f"not in any layer of docs/design.md: {sorted(modules - set(where))}"
    later = [(m, d) for m in modules for d in _imports(os.path.join(PACKAGE, m + ".py")) & modules
             if where[d] > where[m]]
    assert not later, f"imports of a later layer: {later}"


def test_tomllib_is_imported_with_its_python_3_10_fallback():
    """pyproject.toml takes Python 3.10, which has no tomllib: each import of it sits in a try whose handler
    imports tomli (a bare one broke Editor.load there)."""
    for name in sorted(os.listdir(PACKAGE)):
        if not name.endswith(".py"):
            continue
        tree = ast.parse(open(os.path.join(PACKAGE, name), encoding="utf-8").read())
        guarded = {id(n) for t in ast.walk(tree) if isinstance(t, ast.Try)
                   and any("tomli" in ast.dump(h) for h in t.handlers) for n in ast.walk(t)}
        for node in ast.walk(tree):
            if isinstance(node, ast.Import) and any(a.name == "tomllib" for a in node.names):
                assert id(node) in guarded, f"warp_biscale/{name}:{node.lineno}: import tomllib without tomli"
