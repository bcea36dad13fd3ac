"""Tests for ``fastdet.files.images``: writing drawings in every format OpenCV offers."""

from __future__ import annotations

import os
import subprocess
import sys

import cv2
import numpy as np
import pytest

from fastdet.errors import InputError
from fastdet.files.images import GREY_ONLY_SUFFIXES, read_image, write_image
from image_files import png_claiming


@pytest.fixture
def drawing():
    rng = np.random.default_rng(5)
    return rng.integers(0, 256, (40, 60, 3), dtype=np.uint8)


@pytest.mark.parametrize("suffix", GREY_ONLY_SUFFIXES + (".PGM",))
def test_a_colour_image_is_written_in_grey_where_the_format_holds_only_grey(
        tmp_path, drawing, suffix):
    """OpenCV refuses a colour image for PGM and PBM ("expects gray image")."""
    path = tmp_path / f"drawn{suffix}"
    write_image(path, drawing)
    written = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert written.shape == drawing.shape[:2]
    if suffix.lower() == ".pgm":   # PBM keeps one bit a pixel
        np.testing.assert_array_equal(written, cv2.cvtColor(drawing, cv2.COLOR_BGR2GRAY))


def test_a_name_that_is_not_utf8_is_written(tmp_path, drawing):
    """cv2.haveImageWriter crashed the process (SIGSEGV) on such a name."""
    name = os.fsdecode(b"bad\xffname.bmp")
    script = ("import sys, numpy as np; from fastdet.files.images import write_image; "
              "write_image(sys.argv[1], np.zeros((8, 8, 3), np.uint8))")
    done = subprocess.run([sys.executable, "-c", script, str(tmp_path / name)],
                          capture_output=True, timeout=60)
    assert done.returncode == 0, done.stderr.decode(errors="replace")
    np.testing.assert_array_equal(read_image(tmp_path / name), np.zeros((8, 8, 3), np.uint8))


def test_a_suffix_that_is_not_utf8_is_refused_in_one_line(tmp_path, drawing):
    path = tmp_path / os.fsdecode(b"image.\xffpg")
    with pytest.raises(InputError, match="OpenCV has no writer for"):
        write_image(path, drawing)
    assert list(tmp_path.iterdir()) == []


def test_an_encoders_complaint_becomes_the_errors_reason(tmp_path, capfd):
    """OpenJPEG cannot compress a 6x6 image; its log lines used to reach the terminal."""
    path = tmp_path / "tiny.jp2"
    with pytest.raises(InputError) as refused:
        write_image(path, np.zeros((6, 6, 3), np.uint8))
    message = str(refused.value)
    assert message.startswith(f"cannot write image {path}: OpenCV could not encode it (")
    assert "\n" not in message and "grfmt_" not in message
    assert capfd.readouterr().err == ""
    assert list(tmp_path.iterdir()) == []


def test_an_image_claiming_more_pixels_than_opencv_decodes_is_refused(tmp_path):
    """OpenCV asserts on it (cv2.error): every verb that reads images ended in an internal error."""
    path = tmp_path / "huge.png"
    path.write_bytes(png_claiming(40000, 40000))
    with pytest.raises(InputError, match=r"^cannot read .*huge\.png as an image \(more pixels "
                                         r"than OpenCV decodes\)$"):
        read_image(path)


def test_detect_refuses_such_an_image_in_one_line(tmp_path):
    path = tmp_path / "huge.png"
    path.write_bytes(png_claiming(40000, 40000))
    result = subprocess.run([sys.executable, "-m", "fastdet.cli", "detect", str(path)],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 2, result.stderr
    assert result.stderr.strip().splitlines() == [
        f"fastdet: error: cannot read {path} as an image (more pixels than OpenCV decodes)"]
