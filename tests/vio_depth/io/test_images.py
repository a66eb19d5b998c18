"""Issue 12, cases 4-6 (images): a JPEG with a corrupt middle is an error naming the file (libjpeg
only warned and the frame was used), an unreadable image is one clear error, and any path,
also one with bytes that are not UTF-8, is read without crashing."""

import errno
import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from vio_core.errors import SequenceFormatError
from vio_depth.io.images import read_rgb_image


def _jpeg(tmp_path: Path, name="a.jpg") -> Path:
    rng = np.random.default_rng(0)
    vv, uu = np.mgrid[0:120, 0:160]
    img = np.stack([uu % 256, vv * 2 % 256, (uu + vv) % 256], -1).astype(np.uint8)
    img = cv2.GaussianBlur(img, (5, 5), 0) + rng.integers(0, 20, img.shape, dtype=np.uint8)
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 90])
    path = tmp_path / name
    path.write_bytes(buf.tobytes())
    return path


def _corrupt_middle(path: Path) -> None:
    b = bytearray(path.read_bytes())
    mid = len(b) // 2
    b[mid: mid + 200] = b"\x55" * 200
    path.write_bytes(bytes(b))


def test_good_jpeg_reads(tmp_path, capfd):
    img = read_rgb_image(_jpeg(tmp_path))
    assert img.shape == (120, 160, 3) and img.dtype == np.uint8
    assert capfd.readouterr().err == ""


def test_jpeg_with_a_corrupt_middle_is_an_error_and_libjpeg_prints_nothing(tmp_path, capfd):
    path = _jpeg(tmp_path)
    _corrupt_middle(path)
    with pytest.raises(SequenceFormatError, match=r"a\.jpg: corrupt JPEG data \(libjpeg: .*premature end"):
        read_rgb_image(path)
    assert "Corrupt JPEG" not in capfd.readouterr().err  # the warning became the error, not noise


def test_jpeg_detected_by_content_not_name(tmp_path):
    path = _jpeg(tmp_path, "frame.png")  # a JPEG under another name is checked all the same
    _corrupt_middle(path)
    with pytest.raises(SequenceFormatError, match="corrupt JPEG"):
        read_rgb_image(path)


def test_truncated_jpeg_is_an_error(tmp_path):
    path = _jpeg(tmp_path)
    path.write_bytes(path.read_bytes()[:1500])
    with pytest.raises(SequenceFormatError, match="truncated JPEG"):
        read_rgb_image(path)


def test_unreadable_image_is_one_error(tmp_path, monkeypatch):
    path = _jpeg(tmp_path)

    def deny(self):
        raise PermissionError(errno.EACCES, "Permission denied", str(self))

    monkeypatch.setattr(Path, "read_bytes", deny)
    with pytest.raises(SequenceFormatError, match="a.jpg: cannot read image: Permission denied"):
        read_rgb_image(path)


@pytest.mark.skipif(os.geteuid() == 0, reason="root reads any file")
def test_unreadable_image_for_real(tmp_path):
    path = _jpeg(tmp_path)
    path.chmod(0)
    with pytest.raises(SequenceFormatError, match="Permission denied"):
        read_rgb_image(path)


def test_path_with_bytes_that_are_not_utf8(tmp_path):
    folder = Path(os.fsdecode(bytes(tmp_path) + b"/seq\xff\xfe"))
    folder.mkdir()
    path = _jpeg(folder)
    assert read_rgb_image(path).shape == (120, 160, 3)
    with pytest.raises(SequenceFormatError) as err:
        read_rgb_image(folder / "missing\udcff.jpg")
    assert "not found" in str(err.value)
