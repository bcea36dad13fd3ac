"""resize_linear against cv2.resize INTER_LINEAR: bit-identical results."""

import cv2
import numpy as np
import pytest

import fastdet.kernels.resize as resize_module
from fastdet.kernels.resize import resize_linear

#: The detector's five search regions of a 1280x720 frame, (x0, y0, x1, y1)
#: in frame pixels, and the sizes they are resized to.
REGIONS = [((320, 396, 960, 460), (1280, 128)), ((0, 360, 1273, 529), (1697, 225)),
           ((426, 396, 843, 621), (417, 225)), ((0, 360, 1262, 614), (721, 145)),
           ((0, 360, 1280, 618), (640, 129))]

#: The horizontal kernels this machine can run: every one is checked.
PATHS = [name for name, usable in (("avx512", resize_module.HAVE_AVX512BW),
                                   ("avx2", resize_module.HAVE_AVX2),
                                   ("ssse3", resize_module.HAVE_SSSE3),
                                   ("scalar", True)) if usable]


@pytest.fixture(params=PATHS)
def path(request, monkeypatch):
    """Run the test with one horizontal kernel forced."""
    order = ["avx512", "avx2", "ssse3", "scalar"]
    level = order.index(request.param)
    monkeypatch.setattr(resize_module, "HAVE_AVX512BW", level <= 0)
    monkeypatch.setattr(resize_module, "HAVE_AVX2", level <= 1)
    monkeypatch.setattr(resize_module, "HAVE_SSSE3", level <= 2)
    return request.param


def reference(image, size):
    result = cv2.resize(image, size, interpolation=cv2.INTER_LINEAR)
    return result.reshape(size[1], size[0], image.shape[2])


def check(image, size):
    expected = reference(image, size)
    got = resize_linear(image, size)
    assert got.shape == expected.shape and got.dtype == np.uint8
    mismatch = np.argwhere(got != expected)
    assert mismatch.size == 0, (f"{image.shape} -> {size}: {len(mismatch)} values differ, "
                                f"first at {mismatch[0]}")


def random_image(rng, height, width, channels):
    return rng.integers(0, 256, (height, width, channels), dtype=np.uint8)


@pytest.mark.parametrize("channels", [1, 3, 4])
def test_random_sizes(path, channels):
    rng = np.random.default_rng(1234 + channels)
    for _ in range(120):
        sh, sw = (int(v) for v in rng.integers(1, 260, 2))
        dh, dw = (int(v) for v in rng.integers(1, 260, 2))
        check(random_image(rng, sh, sw, channels), (dw, dh))


def test_wide_rows_use_every_piece(path):
    """Long rows (many 64-byte blocks, groups, tails), up, down and mixed."""
    rng = np.random.default_rng(7)
    for _ in range(40):
        sh, sw = (int(v) for v in rng.integers(1, 90, 2) * (1, 20))
        dh, dw = (int(v) for v in rng.integers(1, 90, 2) * (1, 20))
        check(random_image(rng, sh, sw, 3), (dw, dh))


@pytest.mark.parametrize("source, size", [
    ((1, 1), (1, 1)), ((1, 1), (7, 5)), ((5, 7), (1, 1)), ((1, 300), (600, 3)),
    ((300, 1), (2, 600)), ((2, 500), (37, 1)), ((500, 2), (1, 37)), ((3, 1000), (4000, 2)),
    ((40, 40), (40, 13)), ((40, 40), (13, 40)), ((4, 5), (5, 4)),
    ((10, 1000), (100, 10)), ((10, 1000), (50, 7)),  # strong downscales: no SIMD window fits
])
@pytest.mark.parametrize("channels", [1, 3])
def test_edge_sizes(path, source, size, channels):
    rng = np.random.default_rng(sum(source) + sum(size))
    check(random_image(rng, source[0], source[1], channels), size)


@pytest.mark.parametrize("channels", [1, 3])
def test_exact_halves_and_doubles(path, channels):
    rng = np.random.default_rng(3)
    for h, w in [(64, 640), (129, 640), (7, 9), (1, 33)]:
        image = random_image(rng, h, w, channels)
        check(image, (2 * w, 2 * h))
        big = random_image(rng, 2 * h, 2 * w, channels)
        check(big, (w, h))


def test_identity_is_a_copy():
    rng = np.random.default_rng(4)
    image = random_image(rng, 30, 50, 3)[5:25, 3:43]
    got = resize_linear(image, (40, 20))
    assert np.array_equal(got, image) and not np.shares_memory(got, image)


def test_strided_inputs(path):
    rng = np.random.default_rng(5)
    frame = random_image(rng, 300, 400, 3)
    for region in [frame[10:200, 17:390], frame[::2, 5:300], frame[3:250, ::3],
                   frame[:, :, ::-1][1:100, 2:300], frame[50:60, 7:8]]:
        for size in [(500, 250), (123, 45), (region.shape[1] * 2, region.shape[0] * 2)]:
            check(region, size)
    wide = random_image(rng, 40, 100, 6)[:, :, ::2]  # channel stride 2 bytes
    check(wide, (77, 55))


def test_real_regions(path, data_dir):
    frame = cv2.imread(str(data_dir / "test_images" / "test1.jpg"))
    assert frame is not None and frame.shape == (720, 1280, 3)
    converted = cv2.cvtColor(frame, cv2.COLOR_BGR2HLS)[360:648]
    for (x0, y0, x1, y1), size in REGIONS:
        region = converted[y0 - 360:y1 - 360, x0:x1]
        assert not region.flags.c_contiguous or region.shape[1] == 1280
        check(region, size)


def test_out_reuse():
    rng = np.random.default_rng(6)
    out = np.full((45, 123, 3), 7, dtype=np.uint8)
    for _ in range(3):
        image = random_image(rng, 100, 200, 3)
        result = resize_linear(image, (123, 45), out=out)
        assert result is out
        assert np.array_equal(out, reference(image, (123, 45)))
    same = np.full((100, 200, 3), 9, dtype=np.uint8)
    image = random_image(rng, 100, 200, 3)
    assert resize_linear(image, (200, 100), out=same) is same
    assert np.array_equal(same, image)


@pytest.mark.parametrize("image, size, out", [
    (np.zeros((10, 10, 3), np.float32), (5, 5), None),
    (np.zeros((10, 10, 3), np.uint16), (5, 5), None),
    (np.zeros((10, 10), np.uint8), (5, 5), None),
    (np.zeros((2, 10, 10, 3), np.uint8), (5, 5), None),
    ([[[0]]], (5, 5), None),
    (np.zeros((10, 10, 3), np.uint8), (0, 5), None),
    (np.zeros((10, 10, 3), np.uint8), (5, 0), None),
    (np.zeros((10, 10, 3), np.uint8), (-5, 5), None),
    (np.zeros((10, 10, 3), np.uint8), (5,), None),
    (np.zeros((0, 10, 3), np.uint8), (5, 5), None),
    (np.zeros((10, 0, 3), np.uint8), (5, 5), None),
    (np.zeros((10, 10, 0), np.uint8), (5, 5), None),
    (np.zeros((10, 10, 3), np.uint8), (5, 4), np.zeros((5, 4, 3), np.uint8)),
    (np.zeros((10, 10, 3), np.uint8), (5, 4), np.zeros((4, 5, 1), np.uint8)),
    (np.zeros((10, 10, 3), np.uint8), (5, 4), np.zeros((4, 5, 3), np.int16)),
    (np.zeros((10, 10, 3), np.uint8), (5, 4), np.zeros((4, 10, 3), np.uint8)[:, ::2]),
    (np.zeros((10, 10, 3), np.uint8), (10, 10), np.zeros((10, 10, 3), np.uint8)[:, :, :2]),
])
def test_bad_inputs(image, size, out):
    with pytest.raises(ValueError):
        resize_linear(image, size, out=out)


def test_read_only_out_rejected():
    out = np.zeros((4, 5, 3), np.uint8)
    out.flags.writeable = False
    with pytest.raises(ValueError):
        resize_linear(np.zeros((10, 10, 3), np.uint8), (5, 4), out=out)


def test_check_detects_a_difference(monkeypatch):
    """The comparison used above fails on a one-value difference."""
    rng = np.random.default_rng(8)
    image = random_image(rng, 20, 30, 3)
    real = resize_module.resize_linear

    def off_by_one(image, size, out=None):
        result = real(image, size, out)
        result[3, 4, 1] ^= 1
        return result

    monkeypatch.setitem(globals(), "resize_linear", off_by_one)
    with pytest.raises(AssertionError):
        check(image, (17, 11))


@pytest.mark.parametrize("channels", [1, 3, 4])
@pytest.mark.parametrize("height, width", [(2, 2), (2, 94), (4, 96), (6, 98), (30, 34),
                                           (258, 1280), (258, 1278), (11 * 2, 45 * 2)])
def test_exact_halving_matches_opencv(height, width, channels):
    # OpenCV switches to its INTER_AREA path here; the halving kernel must
    # agree, vector blocks (16 pixels of 3 channels) and tails alike.
    image = np.random.default_rng(height * width + channels).integers(
        0, 256, (height, width, channels), dtype=np.uint8)
    check(image, (width // 2, height // 2))
    rows = np.empty((height // 2, width // 2 * channels), np.uint8)
    resize_module._halve(image.reshape(height, width * channels), channels, rows)
    np.testing.assert_array_equal(rows.reshape(height // 2, width // 2, channels),
                                  reference(image, (width // 2, height // 2)))


def test_exact_halving_of_a_frame_region_view(data_dir):
    frame = cv2.imread(str(data_dir / "test_images" / "test1.jpg"))
    region = frame[360:618, 2:1280]          # strided rows, like the 128-px scale's
    check(region, (639, 129))
