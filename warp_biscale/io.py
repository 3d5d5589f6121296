"""File helpers: atomic writes, and the versioned npz format every saved object uses.

A saved file is an ``.npz`` whose ``header`` entry is a JSON document
``{"format": "warp_biscale.<kind>", "version": N, ...}``. `load` reads the header first and refuses
a wrong kind, an unknown version, a truncated or a corrupt file with a message naming the file.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
import zipfile

import numpy as np


__all__ = ["atomic_path", "cache_folder", "check_output", "save_npz", "read_npz", "write_error"]

CACHE_ENV = "WARP_BISCALE_CACHE"


def check_output(path, suffixes=None, what: str = "output", why: str = "") -> None:
    """Refuse, before any work, an output path that cannot be written, in one line naming it: a suffix not
    in `suffixes` (lower-case, with the dot; `why` says why those), an existing directory, or a folder (the
    nearest one that exists: atomic_path makes the missing ones) that is not a directory or takes no new file. The
    folder is tried by creating and removing a temporary file in it, so what the system would refuse
    (a read-only file system, a folder without write permission for this user) is refused here."""
    path = os.fspath(path)
    if os.path.isdir(path):
        raise ValueError(f"{what} {path!r} is a directory; give a file name")
    if suffixes is not None and os.path.splitext(path)[1].lower() not in suffixes:
        if os.path.basename(path).lower() in suffixes:  # (".png": a suffix with no name before it)
            raise ValueError(f"{what} {path!r} has no name before its {os.path.basename(path)}")
        raise ValueError(f"{what} {path!r} must end in {', '.join(suffixes)}" + (f" ({why})" if why else ""))
    folder = os.path.dirname(os.path.abspath(path))
    while not os.path.exists(folder):
        folder = os.path.dirname(folder)
    if not os.path.isdir(folder):
        raise ValueError(f"{what} {path!r} cannot be written: {folder!r} is a file, not a directory")
    try:
        fd, probe = tempfile.mkstemp(prefix=".tmp-check-", dir=folder)
    except OSError as exc:
        raise ValueError(f"{what} {path!r} cannot be written: {exc.strerror or exc} ({folder})") from None
    os.close(fd)
    os.remove(probe)


def cache_folder() -> str:
    """Where computed constants are kept between processes (as Warp keeps its kernels): $WARP_BISCALE_CACHE,
    else $XDG_CACHE_HOME/warp_biscale, else ~/.cache/warp_biscale. Nothing in it is needed: a missing,
    stale or unreadable entry is computed again."""
    if os.environ.get(CACHE_ENV):
        return os.environ[CACHE_ENV]
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "warp_biscale")


def write_error(path, exc: OSError) -> OSError:
    """`exc`, a failed write's OSError, as one line naming the file or folder the user asked for,
    "<path> could not be written: No space left on device": the system's own text names no file (ENOSPC), or a
    temporary the user never asked for. Its type (PermissionError, …) and errno are kept, so that callers can
    tell the causes apart; strerror and filename are left unset, as Python would otherwise print them in its own
    "[Errno N] …: 'file'" form instead of this text."""
    reason = exc.strerror or str(exc) or type(exc).__name__
    message = f"{os.fspath(path)} could not be written: {reason}"
    try:
        out = type(exc)(message)
    except TypeError:  # (a subclass whose constructor takes other arguments)
        out = OSError(message)
    out.errno = exc.errno
    return out


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path beside `path`; on success move it into place, else remove it.

    A reader never sees a half-written file, and a failed write leaves the old file untouched. An OSError of
    the write (a full disk, a read-only folder) names `path` (`write_error`); one that names another file (an
    input read inside the block) is left as it is.
    """
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    tmp = None
    try:
        os.makedirs(folder, exist_ok=True)
        suffix = os.path.splitext(path)[1]
        fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=suffix, dir=folder)
        os.close(fd)
        yield tmp
        # mkstemp makes the file private (0600); give it the mode a plain open() would.
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except OSError as exc:
        _remove(tmp)
        if tmp is not None and exc.filename not in (None, tmp, path):
            raise  # (about another file: its own message names it)
        raise write_error(path, exc) from exc
    except BaseException:
        _remove(tmp)
        raise


def _remove(tmp) -> None:
    if tmp is not None:
        with contextlib.suppress(OSError):
            os.remove(tmp)


def save_npz(path, kind: str, version: int, header: dict, arrays: dict) -> None:
    """Write arrays + a JSON header atomically as a compressed npz."""
    head = {"format": f"warp_biscale.{kind}", "version": int(version), **header}
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, header=np.array(json.dumps(head)), **arrays)


def read_npz(path, kind: str | None = None, versions=(1,)) -> tuple[dict, dict]:
    """→ (header, arrays). Clear errors for a missing, truncated, corrupt or foreign file."""
    path = os.fspath(path)
    if not os.path.exists(path):
        raise FileNotFoundError(f"no such file: {path}")
    if os.path.isdir(path):
        raise ValueError(f"{path} is a folder, not a warp_biscale file")
    with open(path, "rb") as fh:
        if fh.read(2) != b"PK":  # (numpy would try a pickle, and its message says so)
            raise ValueError(f"{path} is truncated or corrupt, or not a warp_biscale file (not an .npz archive)")
    try:
        with np.load(path, allow_pickle=False) as z:
            if "header" not in z.files:
                raise ValueError(f"{path} is not a warp_biscale file (no header)")
            head = json.loads(str(z["header"]))
            if not isinstance(head, dict):  # (valid JSON, but a list or a number: no format, no version)
                raise ValueError(f"{path} is truncated or corrupt, or not a warp_biscale file (its header is a "
                                 f"JSON {type(head).__name__}, not an object)")
            arrays = {k: z[k] for k in z.files if k != "header"}
    except (zipfile.BadZipFile, EOFError, OSError, json.JSONDecodeError, KeyError) as exc:
        raise ValueError(f"{path} is truncated or corrupt: {exc}") from None
    except ValueError as exc:
        if "warp_biscale" in str(exc):
            raise
        raise ValueError(f"{path} is truncated or corrupt: {exc}") from None
    fmt = head.get("format", "")
    if not str(fmt).startswith("warp_biscale."):
        raise ValueError(f"{path} is not a warp_biscale file (format {fmt!r})")
    if kind is not None and fmt != f"warp_biscale.{kind}":
        raise ValueError(f"{path} holds a {fmt!r}, not a warp_biscale.{kind}")
    if head.get("version") not in versions:
        raise ValueError(
            f"{path} is {fmt} version {head.get('version')!r}; this warp_biscale reads version(s) "
            f"{', '.join(map(str, versions))}"
        )
    return head, arrays


