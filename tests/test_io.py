"""File helpers (warp_biscale.io): a failed atomic write names the file it was writing, keeps the old file and
leaves no temporary; a versioned npz whose header is not a JSON object is refused in one line naming the file.

A full disk is simulated (tests cannot mount a small file system): the write raises OSError(ENOSPC), as a
full disk's write() does, with no file name in it."""

import errno
import os

import numpy as np
import pytest

import warp_biscale as wb
from warp_biscale import io


def _full_disk(*args, **kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def _unwritable_dir(tmp_path):
    d = tmp_path / "locked"
    d.mkdir()
    d.chmod(0o500)
    return d


def test_a_full_disk_names_the_file_keeps_the_old_one_and_leaves_no_temporary(tmp_path, monkeypatch):
    path = tmp_path / "m.npz"
    io.save_npz(path, "thing", 1, {"note": "old"}, {"a": np.arange(3)})
    old = path.read_bytes()
    monkeypatch.setattr(io.np, "savez_compressed", _full_disk)
    with pytest.raises(OSError) as info:
        io.save_npz(path, "thing", 1, {"note": "new"}, {"a": np.arange(4)})
    assert str(info.value) == f"{path} could not be written: No space left on device"
    assert info.value.errno == errno.ENOSPC  # (kept, for a caller that tells the causes apart)
    assert path.read_bytes() == old and os.listdir(tmp_path) == ["m.npz"]


def test_an_image_write_on_a_full_disk_names_the_image(tmp_path, monkeypatch):
    """What `render -o x.png` prints: the PNG's path, not Python's bare "[Errno 28] No space left on device"."""
    from PIL import Image

    path = tmp_path / "x.png"
    monkeypatch.setattr(Image.Image, "save", _full_disk)
    with pytest.raises(OSError, match=r"^.*x\.png could not be written: No space left on device$"):
        wb.write_image(str(path), np.full((4, 4, 3), 0.5, np.float32))
    assert os.listdir(tmp_path) == []


@pytest.mark.skipif(os.geteuid() == 0, reason="permissions do not stop root")
def test_a_read_only_folder_names_the_file_not_a_temporary(tmp_path):
    locked = _unwritable_dir(tmp_path)
    for path in (locked / "m.npz", locked / "sub" / "m.npz"):  # (in it; in a folder to be made in it)
        with pytest.raises(PermissionError) as info:
            io.save_npz(path, "thing", 1, {}, {"a": np.arange(3)})
        assert str(info.value) == f"{path} could not be written: Permission denied"
    assert os.listdir(locked) == []


def test_an_error_about_another_file_is_left_as_it_is(tmp_path):
    """An input read inside the block (its error names that file) is not said to be the output's failure."""
    with pytest.raises(FileNotFoundError, match="no-such-input"):
        with io.atomic_path(tmp_path / "out.txt"):
            open(tmp_path / "no-such-input")
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("header", ["[1, 2]", "7", '"text"', "null"])
def test_a_header_that_is_not_a_json_object_is_one_line_naming_the_file(tmp_path, header):
    path = tmp_path / "m.wbm"
    with open(path, "wb") as fh:
        np.savez(fh, header=np.array(header), amplitudes=np.zeros(3))
    for read in (lambda: io.read_npz(path), lambda: io.read_npz(path, "effective_brdf"), lambda: wb.load(path),
                 lambda: wb.EffectiveBRDF.load(path)):
        with pytest.raises(ValueError) as info:
            read()
        assert str(info.value).startswith(f"{path} is truncated or corrupt, or not a warp_biscale file")
        assert "\n" not in str(info.value)
