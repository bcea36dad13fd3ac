"""fastdet.kernels.convert.bgr_to_hls against cv2.cvtColor(..., COLOR_BGR2HLS)."""

import json
import os
import subprocess
import sys

import cv2
import numpy as np
import pytest
from naive import OPENCV_RULES_APART, opencv_hls, opencv_simd_lanes

from fastdet.kernels.convert import _bgr_to_hls_scalar, bgr_to_hls


def reference(image):
    # OpenCV's AVX2 code, which fastdet follows on every CPU (on an AVX-512
    # CPU OpenCV's own output differs from it past whole runs of 16).
    return opencv_hls(image)


@pytest.fixture(scope="module")
def all_colours():
    """Every BGR colour once, as a 4096 x 4096 image."""
    v = np.arange(1 << 24, dtype=np.uint32)
    image = np.stack([v & 255, (v >> 8) & 255, v >> 16], -1).astype(np.uint8)
    return image.reshape(4096, 4096, 3)


def assert_same(got, image):
    want = reference(image)
    assert got.shape == want.shape and got.dtype == np.uint8
    bad = np.argwhere((got != want).any(-1))
    assert bad.size == 0, f"{len(bad)} pixels differ, first {bad[:3].tolist()}"


def test_all_colours_vector_path(all_colours):
    # Width 4096: every pixel goes through the 16-pixel vector blocks.
    assert_same(bgr_to_hls(all_colours), all_colours)


def test_all_colours_scalar_path(all_colours):
    assert_same(_bgr_to_hls_scalar(all_colours), all_colours)


def test_all_colours_tail_path(all_colours):
    # Width 15: every pixel goes through the scalar tail loop of bgr_to_hls,
    # and OpenCV converts pixels 8-14 of each row with its scalar code (its
    # AVX2 code), or all 15 (its AVX-512 code, 16 lanes).
    flat = all_colours.reshape(-1, 3)
    image = flat[: (flat.shape[0] // 15) * 15].reshape(-1, 15, 3)
    assert_same(bgr_to_hls(image), image)


def test_the_reference_is_this_opencv_on_this_cpu(all_colours):
    # opencv_hls rebuilt from OpenCV's two codes is OpenCV's own output, with
    # the runs this OpenCV takes on this CPU (8 or 16 lanes).
    lanes = opencv_simd_lanes()
    assert lanes in (8, 16)
    flat = all_colours.reshape(-1, 3)
    for width in (13, 15, 24, 300):
        image = flat[: len(flat) // width * width].reshape(-1, width, 3)
        assert np.array_equal(opencv_hls(image, lanes), cv2.cvtColor(image, cv2.COLOR_BGR2HLS))
    if lanes == 16:
        # Where they part, fastdet follows OpenCV's AVX2 code, not this one.
        image = flat[: len(flat) // 15 * 15].reshape(-1, 15, 3)
        assert not np.array_equal(opencv_hls(image, 8), opencv_hls(image, 16))


_AVX2_OPENCV = """
import json
import numpy as np
import cv2
from fastdet.kernels.convert import bgr_to_hls
from naive import opencv_simd_lanes
v = np.arange(1 << 24, dtype=np.uint32)
flat = np.stack([v & 255, (v >> 8) & 255, v >> 16], -1).astype(np.uint8)
bad = {}
for width in (15, 24):
    image = flat[: len(flat) // width * width].reshape(-1, width, 3)
    bad[width] = int((bgr_to_hls(image) != cv2.cvtColor(image, cv2.COLOR_BGR2HLS)).any(-1).sum())
print(json.dumps({"lanes": opencv_simd_lanes(), "bad": bad}))
"""


def test_equal_to_opencv_itself_running_its_avx2_code():
    # OpenCV told not to run its AVX-512 code (a no-op on AVX2 CPUs) runs its
    # AVX2 code, which fastdet's output then equals on every colour.
    tests = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env = dict(os.environ, OPENCV_CPU_DISABLE="AVX512-SKX",
               PYTHONPATH=os.pathsep.join(filter(None, [tests, os.environ.get("PYTHONPATH")])))
    done = subprocess.run([sys.executable, "-c", _AVX2_OPENCV], env=env, capture_output=True,
                          text=True, timeout=300, check=True)
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result == {"lanes": 8, "bad": {"15": 0, "24": 0}}


@pytest.mark.parametrize("lanes", [4, 8, 16])
@pytest.mark.parametrize("width", [1, 7, 13, 15, 24, 31, 255, 256, 300, 527])
def test_each_pixel_takes_the_rule_of_its_place(lanes, width):
    # Naively: OpenCV's chunks of 256 pixels, SIMD for whole runs of lanes.
    rng = np.random.default_rng(width * 100 + lanes)
    image = rng.integers(0, 256, (5, width, 3), dtype=np.uint8)
    image[:, ::3] = OPENCV_RULES_APART
    simd = _bgr_to_hls_scalar(image, lanes=1)
    scalar = _bgr_to_hls_scalar(image, lanes=512)
    assert not np.array_equal(simd, scalar)
    x = np.arange(width)
    start = x // 256 * 256
    takes_simd = x - start < np.minimum(256, width - start) // lanes * lanes
    want = np.where(takes_simd[None, :, None], simd, scalar)
    assert np.array_equal(_bgr_to_hls_scalar(image, lanes=lanes), want)
    if width < 256:
        assert takes_simd.sum() == width // lanes * lanes


def test_hue_saturation_not_trivial(all_colours):
    # Guard against a reference that would make the tests vacuous.
    hls = reference(all_colours)
    for c, top in enumerate((180, 255, 255)):
        assert hls[..., c].min() == 0 and hls[..., c].max() == top


@pytest.mark.parametrize("width", list(range(1, 41)) + [63, 64, 65, 1279, 1280, 1283])
def test_random_widths(width):
    rng = np.random.default_rng(width)
    for height in (1, 3, 7):
        image = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
        assert_same(bgr_to_hls(image), image)


def test_greys_and_extremes():
    values = np.array([0, 1, 2, 127, 128, 254, 255], np.uint8)
    b, g, r = np.meshgrid(values, values, values, indexing="ij")
    image = np.stack([b, g, r], -1).reshape(1, -1, 3)
    assert_same(bgr_to_hls(image), image)
    assert_same(bgr_to_hls(image.reshape(-1, 1, 3)), image.reshape(-1, 1, 3))


def test_tiny_and_empty():
    image = np.array([[[10, 200, 30]]], np.uint8)
    assert_same(bgr_to_hls(image), image)
    for shape in ((0, 5, 3), (5, 0, 3), (0, 0, 3)):
        assert bgr_to_hls(np.zeros(shape, np.uint8)).shape == shape


@pytest.mark.parametrize("start,stop", [(0, 37), (1, 50), (3, 40), (5, 1280), (7, 100)])
def test_column_slices(start, stop):
    rng = np.random.default_rng(start * 1000 + stop)
    frame = rng.integers(0, 256, (21, 1283, 3), dtype=np.uint8)
    image = frame[2:19, start:stop]
    assert not image.flags.c_contiguous
    assert_same(bgr_to_hls(image), image)


def test_other_strides():
    rng = np.random.default_rng(5)
    frame = rng.integers(0, 256, (30, 70, 3), dtype=np.uint8)
    for image in (frame[::-1], frame[::2, ::3], frame[:, ::-1], frame[..., ::-1],
                  np.asfortranarray(frame)):
        assert_same(bgr_to_hls(image), image)


def test_out_reused():
    rng = np.random.default_rng(9)
    out = np.full((13, 45, 3), 7, np.uint8)
    for _ in range(3):
        image = rng.integers(0, 256, (13, 45, 3), dtype=np.uint8)
        result = bgr_to_hls(image, out=out)
        assert result is out
        assert_same(out, image)


def test_input_unchanged():
    rng = np.random.default_rng(11)
    image = rng.integers(0, 256, (9, 33, 3), dtype=np.uint8)
    copy = image.copy()
    bgr_to_hls(image)
    assert np.array_equal(image, copy)


@pytest.mark.parametrize("image", [
    np.zeros((4, 4, 3), np.float32),
    np.zeros((4, 4, 3), np.int16),
    np.zeros((4, 4), np.uint8),
    np.zeros((4, 4, 3, 1), np.uint8),
    np.zeros((4, 4, 4), np.uint8),
    np.zeros((4, 4, 1), np.uint8),
    [[[1, 2, 3]]],
])
def test_bad_image(image):
    with pytest.raises(ValueError):
        bgr_to_hls(image)


@pytest.mark.parametrize("out", [
    np.zeros((4, 5, 3), np.uint8),
    np.zeros((5, 4, 3), np.uint8),
    np.zeros((4, 4, 3), np.float32),
    np.zeros((4, 8, 3), np.uint8)[:, ::2],
    np.zeros((4, 4, 3), np.uint8, order="F"),
    "nope",
])
def test_bad_out(out):
    with pytest.raises(ValueError):
        bgr_to_hls(np.zeros((4, 4, 3), np.uint8), out=out)


def test_read_only_out():
    out = np.zeros((4, 4, 3), np.uint8)
    out.flags.writeable = False
    with pytest.raises(ValueError):
        bgr_to_hls(np.zeros((4, 4, 3), np.uint8), out=out)
