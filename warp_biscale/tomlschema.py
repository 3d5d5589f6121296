"""Reading a TOML file against a schema, with every error located: a `SceneError` names the file, the
line, the table and the key (`scene.toml:12: [material.gold] exponent must be ...`). tomllib gives no
positions, so `_Locator` finds each key's line in the text itself; `_read` checks a table's keys and
types, `_build` calls a constructor with them and moves its ValueError (and its energy and tile
warnings) to the line of the key it names."""

from __future__ import annotations

import contextlib
import math
import os
import re
import warnings


from .brdf import EnergyWarning
from .smallscale import TileWarning

class SceneError(ValueError):
    """A bad scene file: `path`, `line` (1-based, or None) and `key` (None for a whole table)."""

    def __init__(self, message, path=None, line=None, key=None):
        super().__init__(message)
        self.path, self.line, self.key = path, line, key


# ------------------------------------------------------------------------------------------------
# key → line

_BARE = r'[A-Za-z0-9_-]+|"(?:[^"\\]|\\.)*"|\'[^\']*\''
_KEY_RE = re.compile(rf"^\s*((?:{_BARE})(?:\s*\.\s*(?:{_BARE}))*)\s*=")
_HEADER_RE = re.compile(rf"^\s*(\[\[?)\s*((?:{_BARE})(?:\s*\.\s*(?:{_BARE}))*)\s*(\]\]?)\s*(#.*)?$")
_INLINE_KEY_RE = re.compile(rf"[{{,]\s*((?:{_BARE})(?:\s*\.\s*(?:{_BARE}))*)\s*=")


def _split_key(text: str) -> tuple:
    return tuple(p[1:-1] if p[0] in "\"'" else p for p in re.findall(_BARE, text))


class _Locator:
    """Where each key and table of a TOML text is: (table path + dotted key) → 1-based line.

    Arrays of tables get their element index in the path: ``[[object]]`` #2's ``mesh`` is
    ("object", 1, "mesh"). Keys inside an inline table are found on their line too."""

    def __init__(self, text: str):
        self.lines: dict = {}
        arrays: dict = {}
        table: tuple = ()
        in_string = None
        for no, raw in enumerate(text.splitlines(), 1):
            if in_string:
                if raw.count(in_string) % 2 == 1:
                    in_string = None
                continue
            m = _HEADER_RE.match(raw)
            if m and not _KEY_RE.match(raw):
                names = _split_key(m.group(2))
                path: tuple = ()
                for i, name in enumerate(names):
                    path += (name,)
                    if names[: i + 1] in arrays and i < len(names) - 1:
                        path += (arrays[names[: i + 1]],)
                if m.group(1) == "[[":
                    arrays[names] = arrays.get(names, -1) + 1
                    path += (arrays[names],)
                table = path
                self.lines.setdefault(table, no)
                continue
            m = _KEY_RE.match(raw)
            if m:
                key = table + _split_key(m.group(1))
                self.lines.setdefault(key, no)
                rest = raw[m.end():]
                for k in _INLINE_KEY_RE.finditer(rest):
                    self.lines.setdefault(key + _split_key(k.group(1)), no)
                for quote in ('"""', "'''"):
                    if rest.count(quote) % 2 == 1:
                        in_string = quote

    def line(self, path: tuple):
        """The line of `path`, else of its closest enclosing key or table (None if none is written)."""
        path = tuple(path)
        while path:
            if path in self.lines:
                return self.lines[path]
            path = path[:-1]
        return None


# ------------------------------------------------------------------------------------------------
# typed access to one table


def _show(v) -> str:
    return repr(v) if isinstance(v, str) else str(v).replace("'", '"') if isinstance(v, (list, dict)) else str(v)


class _Ctx:
    """The file being read: its name, directory and key locator; `error` builds a located SceneError."""

    def __init__(self, text, path, base_dir):
        self.path = path
        self.name = os.path.basename(path) if path else "<scene>"
        self.base_dir = base_dir
        self.loc = _Locator(text)

    def error(self, table: tuple, key, message):
        where = key if isinstance(key, tuple) else (() if key is None else (key,))
        line = self.loc.line(table + where)
        head = f"{self.name}:{line}:" if line else f"{self.name}:"
        return SceneError(f"{head} {_table_name(table)} {message}", self.path, line,
                          ".".join(map(str, where)) or None)

    def resolve(self, rel: str) -> str:
        p = os.path.expanduser(rel)
        return p if os.path.isabs(p) else os.path.normpath(os.path.join(self.base_dir, p))


def _article(word: str) -> str:
    """"an" before a vowel ("an anisotropicward material"), else "a"."""
    return "an" if word[:1].lower() in "aeiou" else "a"


def _table_name(table: tuple) -> str:
    if not table:
        return "(top level)"
    if isinstance(table[-1], int):
        return f"[[{'.'.join(map(str, table[:-1]))}]] #{table[-1] + 1}"
    return "[" + ".".join(map(str, table)) + "]"


def _is_num(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _check_number(v):
    if not _is_num(v):
        return None, "a number"
    if not math.isfinite(v):
        return None, "a finite number"
    return float(v), None


def _check_int(v):
    if not isinstance(v, int) or isinstance(v, bool):
        return None, "an integer"
    return v, None


def _check_vec3(v):
    if not (isinstance(v, list) and len(v) == 3 and all(_is_num(x) for x in v)):
        return None, "three numbers [x, y, z]"
    if not all(math.isfinite(x) for x in v):
        return None, "three finite numbers [x, y, z] (no nan or inf)"
    return [float(x) for x in v], None


def _check_rgb(v):
    if _is_num(v) or (isinstance(v, list) and len(v) == 3 and all(_is_num(x) for x in v)):
        if not all(math.isfinite(x) for x in (v if isinstance(v, list) else [v])):
            return None, "a finite number or an RGB triple of them (no nan or inf)"
        return (float(v) if _is_num(v) else [float(x) for x in v]), None
    return None, "a number or an RGB triple [r, g, b]"


def _check_str(v):
    return (v, None) if isinstance(v, str) else (None, "a string")


def _check_int2(v):
    if not (isinstance(v, list) and len(v) == 2 and all(isinstance(x, int) and not isinstance(x, bool) for x in v)):
        return None, "two integers [a, b]"
    return tuple(v), None


def _check_strlist(v):
    if isinstance(v, str):
        return [v], None
    if isinstance(v, list) and v and all(isinstance(x, str) for x in v):
        return list(v), None
    return None, "a string or a non-empty list of strings"


def _check_lobes(v):
    if v == "auto":
        return v, None
    if isinstance(v, int) and not isinstance(v, bool):
        return v, None
    return None, 'an integer or "auto"'


def _check_table(v):
    return (v, None) if isinstance(v, dict) else (None, "a table { key = value, ... }")


def _check_list(v):
    return (v, None) if isinstance(v, list) else (None, "a list")


NUM, INT, VEC3, RGB, STR, INT2, STRLIST, LOBES, TABLE, LIST = (
    _check_number, _check_int, _check_vec3, _check_rgb, _check_str, _check_int2, _check_strlist, _check_lobes,
    _check_table, _check_list)


def _read(ctx: _Ctx, table: tuple, data, schema: dict, required=(), where: str = "") -> dict:
    """Check `data` (a dict) against `schema` (key → checker): unknown keys, missing required keys and
    wrong types are SceneErrors naming the key and its line. → the converted values given."""
    if not isinstance(data, dict):
        raise ctx.error(table, None, f"must be a table, got {_show(data)}")
    for key in data:
        if key not in schema:
            allowed = ", ".join(sorted(schema)) or "none"
            raise ctx.error(table, key, f"unknown key {key!r}{where} (allowed: {allowed})")
    for key in required:
        if key not in data:
            raise ctx.error(table, None, f"needs the key {key!r}{where}")
    out = {}
    for key, value in data.items():
        conv, want = schema[key](value)
        if want is not None:
            raise ctx.error(table, key, f"{key} must be {want}, got {_show(value)}")
        out[key] = conv
    return out


def _build(ctx: _Ctx, table: tuple, values: dict, fn, *args, warn_key=None, **extra):
    """Call a constructor with the table's values; its ValueError gets the line of the key it names, and so
    do its EnergyWarnings and TileWarnings (else they get the line of `warn_key`, else of the table)."""
    try:
        with _located_warnings(ctx, table, values, warn_key):
            return fn(*args, **values, **extra)
    except (ValueError, TypeError) as exc:
        raise _located(ctx, table, values, exc) from None


def _named_key(msg: str, keys):
    """The key of `keys` that `msg` names first (as a whole word), else None."""
    hits = [(m.start(), k) for k in keys for m in [re.search(rf"(?<![A-Za-z0-9_]){re.escape(k)}(?![A-Za-z0-9_])",
                                                              msg)] if m]
    return min(hits)[1] if hits else None


def _located(ctx, table, values, exc) -> SceneError:
    msg = str(exc)
    return ctx.error(table, _named_key(msg, values), msg)


@contextlib.contextmanager
def _located_warnings(ctx: _Ctx, table: tuple, keys, default_key=None):
    """Re-issue the EnergyWarnings (a BRDF's energy gain) and TileWarnings raised inside with the file, line
    and table of the key they name (else `default_key`'s); other warnings pass through unchanged."""
    caught: list = []
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            yield
    finally:  # (also when the body raises: what it warned of before still shows)
        _reissue(ctx, table, keys, default_key, caught)


def _reissue(ctx, table, keys, default_key, caught):

    for w in caught:
        if issubclass(w.category, (EnergyWarning, TileWarning)):
            msg = str(w.message)
            warnings.warn(str(ctx.error(table, _named_key(msg, keys) or default_key, msg)), w.category, stacklevel=4)
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno, source=w.source)
