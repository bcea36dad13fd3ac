"""Tests for the HOG kernels: ``fastdet.kernels.hog.cell_histograms`` and
``fastdet.kernels.blocks.normalize_blocks``.

Both are compared with ``skimage.feature.hog(..., feature_vector=False)``
(per channel, and in its multichannel ``channel_axis=-1`` mode) and with the
plain-numpy references in ``naive.py``, on random and real images.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from skimage.feature import hog as skimage_hog

from fastdet.kernels.blocks import normalize_blocks
from fastdet.kernels.hog import cell_histograms
from naive import naive_cell_histograms, naive_normalize_blocks

NORMS = ("L1", "L1-sqrt", "L2", "L2-Hys")

#: Largest absolute difference allowed between normalised block features.
TOL = 1e-5

#: Image kinds: uint8 (the kernels' lookup-table path), float32 with
#: fractional values and float32 holding integers (the float path; integer
#: gradients often lie exactly on a bin boundary: 0, 45 or 90 degrees).
KINDS = ("uint8", "float32", "float32-int")

#: (image (H, W), pixels_per_cell, cells_per_block, orientations).
CONFIGS = [
    ((37, 53), (8, 8), (2, 2), 9),
    ((65, 67), (6, 6), (3, 3), 8),
    ((65, 67), (7, 7), (1, 1), 12),
    ((37, 53), (8, 6), (2, 2), 7),
    ((53, 37), (6, 8), (3, 3), 9),
    ((9, 9), (8, 8), (1, 1), 9),
    ((64, 64), (8, 8), (2, 2), 9),
    # Block lengths of 4k + 2 and 4k + 3 (the L2-Hys sum's four running sums
    # leave 2 and 3 over; 81 and 9 above leave 1).
    ((41, 43), (8, 8), (1, 1), 10),
    ((41, 43), (8, 8), (1, 1), 11),
]


# -- helpers ----------------------------------------------------------------
def read_image(path, flags=cv2.IMREAD_COLOR):
    image = cv2.imread(str(path), flags)
    if image is None:
        pytest.fail(f"cannot read test image {path} (missing or unreadable; "
                    f"set FASTDET_DATA to the shared data folder)", pytrace=False)
    return image if image.ndim == 3 else image[:, :, None]


@pytest.fixture(scope="module")
def crops(data_dir):
    """The first three 64x64 BGR crops of vehicles/GTI_Far."""
    folder = data_dir / "vehicles" / "GTI_Far"
    paths = sorted(folder.glob("*.png"))[:3]
    if len(paths) < 3:
        pytest.fail(f"expected at least 3 PNG crops in {folder}, found {len(paths)}",
                    pytrace=False)
    return [read_image(path) for path in paths]


@pytest.fixture(scope="module")
def frame_bgr(data_dir):
    """The real 1280x720 test frame test_images/test1.jpg."""
    return read_image(data_dir / "test_images" / "test1.jpg")


def make_image(rng, shape, kind):
    if kind == "uint8":
        return rng.integers(0, 256, shape, dtype=np.uint8)
    if kind == "float32":
        return (rng.random(shape) * 255).astype(np.float32)
    if kind == "float32-int":
        return rng.integers(0, 256, shape).astype(np.float32)
    raise AssertionError(kind)


def as_kind(image_u8, kind):
    return image_u8 if kind == "uint8" else np.ascontiguousarray(image_u8, dtype=np.float32)


def fastdet_blocks(image, ppc, cpb, nbins, norm, merge=False, parallel=False):
    cells = cell_histograms(image, ppc, nbins, merge_channels=merge, parallel=parallel)
    assert cells.dtype == np.float32
    blocks = normalize_blocks(cells, cpb, norm, parallel=parallel)
    assert blocks.dtype == np.float32
    return blocks


def skimage_blocks(image, ppc, cpb, nbins, norm, channel_axis=None):
    return skimage_hog(image, orientations=nbins, pixels_per_cell=ppc, cells_per_block=cpb,
                       block_norm=norm, feature_vector=False, channel_axis=channel_axis)


def assert_close(actual, expected, what):
    assert actual.shape == expected.shape, f"{what}: shape {actual.shape} != {expected.shape}"
    if actual.size:
        diff = float(np.max(np.abs(actual.astype(np.float64) - expected)))
        worst = np.unravel_index(np.argmax(np.abs(actual - expected)), actual.shape)
        assert diff < TOL, (f"{what}: max abs diff {diff:.3g} at {worst}: "
                            f"{actual[worst]!r} vs {expected[worst]!r}")


def assert_matches_skimage_per_channel(image, ppc, cpb, nbins, norm):
    """fastdet's per-channel HOG == skimage's HOG of each channel alone."""
    height, width, channels = image.shape
    blocks = fastdet_blocks(image, ppc, cpb, nbins, norm)
    hb = height // ppc[0] - cpb[0] + 1
    wb = width // ppc[1] - cpb[1] + 1
    assert blocks.shape == (hb, wb, channels * cpb[0] * cpb[1] * nbins)
    per_channel = blocks.reshape(hb, wb, channels, cpb[0], cpb[1], nbins)
    for c in range(channels):
        expected = skimage_blocks(image[:, :, c], ppc, cpb, nbins, norm)
        assert_close(per_channel[:, :, c], expected, f"channel {c}")


def assert_matches_skimage_merged(image, ppc, cpb, nbins, norm):
    """merge_channels=True == skimage's multichannel (channel_axis=-1) HOG."""
    height, width, _ = image.shape
    blocks = fastdet_blocks(image, ppc, cpb, nbins, norm, merge=True)
    hb = height // ppc[0] - cpb[0] + 1
    wb = width // ppc[1] - cpb[1] + 1
    assert blocks.shape == (hb, wb, cpb[0] * cpb[1] * nbins)
    expected = skimage_blocks(image, ppc, cpb, nbins, norm, channel_axis=-1)
    assert_close(blocks.reshape(hb, wb, cpb[0], cpb[1], nbins), expected, "merged")


def assert_cells_match_naive(image, ppc, nbins, merge=False):
    actual = cell_histograms(image, ppc, nbins)
    expected = naive_cell_histograms(image, ppc, nbins)
    assert actual.shape == expected.shape
    scale = max(1.0, float(np.abs(expected).max(initial=0.0)))
    np.testing.assert_allclose(actual, expected, rtol=1e-5, atol=1e-5 * scale)


# -- scikit-image, random images --------------------------------------------
@pytest.mark.parametrize("config", CONFIGS, ids=lambda c: f"{c[0][0]}x{c[0][1]}-ppc{c[1][0]}x"
                         f"{c[1][1]}-cpb{c[2][0]}-o{c[3]}")
@pytest.mark.parametrize("norm", NORMS)
@pytest.mark.parametrize("channels", [1, 3])
@pytest.mark.parametrize("kind", KINDS)
def test_per_channel_matches_skimage_random(kind, channels, norm, config):
    (height, width), ppc, cpb, nbins = config
    rng = np.random.default_rng(height * 1000 + width + channels)
    image = make_image(rng, (height, width, channels), kind)
    assert_matches_skimage_per_channel(image, ppc, cpb, nbins, norm)


@pytest.mark.parametrize("config", CONFIGS[:5], ids=lambda c: f"{c[0][0]}x{c[0][1]}-ppc{c[1][0]}x"
                         f"{c[1][1]}-cpb{c[2][0]}-o{c[3]}")
@pytest.mark.parametrize("norm", NORMS)
@pytest.mark.parametrize("kind", KINDS)
def test_merged_channels_match_skimage_multichannel(kind, norm, config):
    (height, width), ppc, cpb, nbins = config
    rng = np.random.default_rng(7 + height + width)
    image = make_image(rng, (height, width, 3), kind)
    assert_matches_skimage_merged(image, ppc, cpb, nbins, norm)


def test_merged_channels_pick_the_strongest_channel_per_pixel():
    # Three channels whose gradients point in three different bins with
    # different strengths in different places: the merged histogram must
    # follow the strongest one, pixel by pixel, not add them up.
    rng = np.random.default_rng(3)
    image = np.zeros((24, 24, 3), np.float32)
    ramp = np.arange(24, dtype=np.float32)
    image[:, :, 0] = ramp[None, :] * 2.0          # 0 degrees, magnitude 4
    image[:, :, 1] = ramp[:, None] * 3.0          # 90 degrees, magnitude 6
    image[:12, :, 2] = (ramp[None, :] + ramp[:12, None]) * 5.0  # 45 degrees, magnitude 14
    image += rng.random(image.shape, dtype=np.float32) * 1e-3
    assert_matches_skimage_merged(np.ascontiguousarray(image), (6, 6), (2, 2), 9, "L1")


# -- scikit-image, edge sizes ----------------------------------------------
@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("shape, ppc, cpb", [
    ((1, 50, 1), (1, 5), (1, 1)),
    ((1, 50, 3), (1, 5), (1, 2)),
    ((50, 1, 3), (5, 1), (2, 1)),
    ((1, 1, 1), (1, 1), (1, 1)),
    ((2, 9, 3), (2, 3), (1, 2)),
])
@pytest.mark.parametrize("norm", ["L1", "L2-Hys"])
def test_thin_images_match_skimage(kind, shape, ppc, cpb, norm):
    rng = np.random.default_rng(shape[1])
    image = make_image(rng, shape, kind)
    assert_matches_skimage_per_channel(image, ppc, cpb, 9, norm)
    assert_cells_match_naive(image, ppc, 9)


@pytest.mark.parametrize("parallel", [False, True])
@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("shape, ppc, cpb", [
    ((7, 7, 3), (8, 8), (2, 2)),      # no cell at all
    ((15, 15, 1), (8, 8), (2, 2)),    # one cell, block of 2x2
    ((16, 40, 3), (8, 8), (3, 3)),    # 2 cell rows, block of 3
    ((40, 16, 1), (8, 8), (3, 3)),    # 2 cell columns, block of 3
    ((1, 50, 3), (8, 8), (1, 1)),     # a 1xN image: no cell row
    ((50, 1, 1), (8, 8), (1, 1)),     # an Nx1 image: no cell column
    ((23, 30, 3), (8, 6), (3, 3)),
])
@pytest.mark.parametrize("merge", [False, True])
def test_images_smaller_than_a_block_give_empty_arrays(parallel, kind, shape, ppc, cpb, merge):
    rng = np.random.default_rng(5)
    image = make_image(rng, shape, kind)
    nbins = 9
    cells = cell_histograms(image, ppc, nbins, merge_channels=merge, parallel=parallel)
    out_channels = 1 if merge else shape[2]
    assert cells.shape == (shape[0] // ppc[0], shape[1] // ppc[1], out_channels, nbins)
    blocks = normalize_blocks(cells, cpb, "L2-Hys", parallel=parallel)
    assert blocks.dtype == np.float32
    assert blocks.shape[0] == 0 or blocks.shape[1] == 0, blocks.shape
    assert blocks.shape == (max(cells.shape[0] - cpb[0] + 1, 0),
                            max(cells.shape[1] - cpb[1] + 1, 0),
                            out_channels * cpb[0] * cpb[1] * nbins)
    assert blocks.size == 0
    # scikit-image agrees that there is no whole block.
    with pytest.raises(ValueError):
        skimage_blocks(image[:, :, 0], ppc, cpb, nbins, "L2-Hys")


def test_unknown_norm_is_rejected():
    cells = cell_histograms(np.zeros((16, 16, 1), np.uint8), (8, 8), 9)
    with pytest.raises(ValueError, match="L3"):
        normalize_blocks(cells, (2, 2), "L3")


# -- scikit-image, orientation bin boundaries ---------------------------------
def boundary_gradients(nbins, rng, per_side=3):
    """float32 gradients whose float64 angle lies within float32 rounding of
    each bin boundary ``k * 180 / nbins``: just below and just above the
    exact (float64) boundary, on both sides of its float32 rounding."""
    found = []
    for k in range(1, nbins):
        exact = 180.0 / nbins * k
        rounded = float(np.float32(exact))
        radius = rng.uniform(20.0, 2000.0, 20000)
        theta = np.deg2rad(exact + rng.uniform(-2e-5, 2e-5, radius.size))
        gx = (radius * np.cos(theta)).astype(np.float32)
        gy = (radius * np.sin(theta)).astype(np.float32)
        angle = np.rad2deg(np.arctan2(gy.astype(np.float64), gx.astype(np.float64))) % 180
        lo, hi = min(exact, rounded), max(exact, rounded)
        for inside in (angle < lo, (angle >= lo) & (angle < hi), angle >= hi):
            picked = np.flatnonzero(inside)[:per_side]
            found.extend(zip(gx[picked], gy[picked]))
    return found


def gradient_probe_image(gradients):
    """A (4 * K, 3) float32 image whose k-th 4x3 cell has gradient
    ``gradients[k]`` at its pixel (1, 1) (plus a vertical one at (3, 1))."""
    image = np.zeros((4 * len(gradients), 3, 1), np.float32)
    for k, (gx, gy) in enumerate(gradients):
        image[4 * k + 1, 2, 0] = gx
        image[4 * k + 2, 1, 0] = gy
    return image


@pytest.mark.parametrize("nbins", [7, 9, 11, 12, 13])
def test_float_gradients_at_bin_boundaries_match_skimage(nbins):
    rng = np.random.default_rng(nbins)
    gradients = boundary_gradients(nbins, rng)
    assert len(gradients) >= nbins  # the search found probes near the boundaries
    image = gradient_probe_image(gradients)
    actual = fastdet_blocks(image, (4, 3), (1, 1), nbins, "L1").reshape(len(gradients), nbins)
    expected = skimage_blocks(image[:, :, 0], (4, 3), (1, 1), nbins, "L1").reshape(
        len(gradients), nbins)
    wrong = []
    for k in np.flatnonzero(np.abs(actual - expected).max(axis=1) >= TOL):
        gx, gy = gradients[k]
        angle = np.rad2deg(np.arctan2(np.float64(gy), np.float64(gx))) % 180
        boundary = round(angle * nbins / 180)
        exact = 180.0 / nbins * boundary
        wrong.append(f"gradient ({gx!r}, {gy!r}) at {angle!r} deg, boundary {exact!r} "
                     f"(float32 {float(np.float32(exact))!r}): fastdet bins "
                     f"{np.round(actual[k], 3).tolist()}, "
                     f"skimage {np.round(expected[k], 3).tolist()}")
    assert not wrong, (f"{len(wrong)} of {len(gradients)} probes binned differently:\n"
                       + "\n".join(wrong))


def test_merged_float32_near_equal_magnitudes_match_skimage():
    # Two channels whose float32 gradient magnitudes are equal (so
    # scikit-image, comparing float32 magnitudes, keeps the first channel)
    # while their float64 magnitudes differ, pointing to different bins.
    rng = np.random.default_rng(11)
    radius = rng.uniform(50, 500, 20000).astype(np.float32)
    theta0 = rng.uniform(0, np.pi, radius.size)
    theta1 = rng.uniform(0, np.pi, radius.size)
    a = np.stack([radius * np.cos(theta0), radius * np.sin(theta0)], 1).astype(np.float32)
    b = np.stack([radius * np.cos(theta1), radius * np.sin(theta1)], 1).astype(np.float32)
    mag32_a, mag32_b = np.hypot(a[:, 0], a[:, 1]), np.hypot(b[:, 0], b[:, 1])
    mag64_a = np.hypot(a[:, 0].astype(np.float64), a[:, 1].astype(np.float64))
    mag64_b = np.hypot(b[:, 0].astype(np.float64), b[:, 1].astype(np.float64))
    picked = np.flatnonzero((mag32_a == mag32_b) & (mag64_a != mag64_b)
                            & (np.abs(theta0 - theta1) > 0.5))[:16]
    assert picked.size == 16
    image = np.zeros((4 * picked.size, 3, 2), np.float32)
    for k, i in enumerate(picked):
        for c, grad in enumerate((a[i], b[i])):
            image[4 * k + 1, 2, c] = grad[0]
            image[4 * k + 2, 1, c] = grad[1]
    actual = fastdet_blocks(image, (4, 3), (1, 1), 9, "L1", merge=True).reshape(picked.size, 9)
    expected = skimage_blocks(image, (4, 3), (1, 1), 9, "L1", channel_axis=-1).reshape(
        picked.size, 9)
    wrong = [f"channel 0 gradient {a[i].tolist()} |g|={mag64_a[i]!r}, channel 1 gradient "
             f"{b[i].tolist()} |g|={mag64_b[i]!r} (float32 |g| both {mag32_a[i]!r}): "
             f"fastdet {np.round(actual[k], 3).tolist()}, "
             f"skimage {np.round(expected[k], 3).tolist()}"
             for k, i in enumerate(picked) if np.abs(actual[k] - expected[k]).max() >= TOL]
    assert not wrong, (f"{len(wrong)} of {picked.size} pixels took another channel than "
                       f"scikit-image:\n" + "\n".join(wrong))


# -- scikit-image, real images ----------------------------------------------
@pytest.mark.parametrize("kind", ["uint8", "float32"])
@pytest.mark.parametrize("norm", NORMS)
@pytest.mark.parametrize("ppc, cpb, nbins", [((8, 8), (2, 2), 9), ((6, 6), (3, 3), 12)])
def test_real_vehicle_crops_match_skimage(crops, kind, norm, ppc, cpb, nbins):
    for crop in crops:
        assert crop.shape == (64, 64, 3) and crop.dtype == np.uint8
        image = as_kind(crop, kind)
        assert_matches_skimage_per_channel(image, ppc, cpb, nbins, norm)
        grey = as_kind(cv2.cvtColor(crop, cv2.COLOR_BGR2GRAY)[:, :, None], kind)
        assert_matches_skimage_per_channel(grey, ppc, cpb, nbins, norm)
        assert_matches_skimage_merged(image, ppc, cpb, nbins, norm)


@pytest.fixture(scope="module")
def frame_grey(data_dir):
    return read_image(data_dir / "test_images" / "test1.jpg", cv2.IMREAD_GRAYSCALE)


def test_real_frame_grey_matches_skimage(frame_grey):
    assert frame_grey.shape == (720, 1280, 1)
    assert_matches_skimage_per_channel(frame_grey, (8, 8), (2, 2), 9, "L2-Hys")


def test_real_frame_grey_float32_matches_skimage(frame_grey):
    assert_matches_skimage_per_channel(frame_grey.astype(np.float32), (8, 8), (2, 2), 9,
                                       "L1-sqrt")


def test_real_frame_grey_matches_naive(frame_grey):
    assert_cells_match_naive(frame_grey, (8, 8), 9)


@pytest.mark.parametrize("kind", ["uint8", "float32"])
@pytest.mark.parametrize("merge", [False, True])
def test_real_frame_parallel_equals_serial(frame_bgr, kind, merge):
    image = as_kind(np.ascontiguousarray(frame_bgr[300:620, 100:1180]), kind)
    serial = cell_histograms(image, (8, 8), 9, merge_channels=merge)
    parallel = cell_histograms(image, (8, 8), 9, merge_channels=merge, parallel=True)
    np.testing.assert_allclose(parallel, serial, rtol=1e-6, atol=1e-6, strict=True)
    for norm in NORMS:
        np.testing.assert_allclose(normalize_blocks(serial, (2, 2), norm, parallel=True),
                                   normalize_blocks(serial, (2, 2), norm),
                                   rtol=1e-6, atol=1e-7, strict=True)


# -- parallel variants ----------------------------------------------------
@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("shape, ppc, cpb, nbins", [
    ((37, 53, 3), (8, 8), (2, 2), 9),
    ((65, 67, 1), (6, 6), (3, 3), 8),
    ((130, 67, 3), (7, 7), (1, 1), 12),
    ((83, 61, 3), (8, 6), (2, 2), 7),
    ((8, 80, 3), (8, 8), (1, 2), 9),
])
@pytest.mark.parametrize("merge", [False, True])
def test_parallel_equals_serial(kind, shape, ppc, cpb, nbins, merge):
    rng = np.random.default_rng(shape[0])
    image = make_image(rng, shape, kind)
    serial = cell_histograms(image, ppc, nbins, merge_channels=merge)
    parallel = cell_histograms(image, ppc, nbins, merge_channels=merge, parallel=True)
    np.testing.assert_allclose(parallel, serial, rtol=1e-6, atol=1e-6, strict=True)
    for norm in NORMS:
        np.testing.assert_allclose(normalize_blocks(serial, cpb, norm, parallel=True),
                                   normalize_blocks(serial, cpb, norm),
                                   rtol=1e-6, atol=1e-7, strict=True)


# -- the naive references (independent of scikit-image) -----------------------
@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("shape, ppc, nbins", [
    ((37, 53, 3), (8, 8), 9),
    ((65, 67, 1), (6, 6), 8),
    ((65, 67, 3), (7, 7), 12),
    ((37, 53, 1), (8, 6), 7),
    ((9, 9, 3), (8, 8), 9),
    ((1, 40, 3), (1, 4), 9),
])
def test_cells_match_naive(kind, shape, ppc, nbins):
    rng = np.random.default_rng(shape[0] + shape[1])
    assert_cells_match_naive(make_image(rng, shape, kind), ppc, nbins)


@pytest.mark.parametrize("kind", ["uint8", "float32"])
def test_cells_of_real_crops_match_naive(crops, kind):
    for crop in crops:
        assert_cells_match_naive(as_kind(crop, kind), (8, 8), 9)


def test_cells_of_a_known_pattern():
    # A horizontal ramp of slope 3: every interior pixel has gradient (6, 0),
    # angle 0, so bin 0 of a cell holds 6 x (its pixels with a gx) / 64.
    image = np.tile(np.arange(16, dtype=np.uint8) * 3, (16, 1))[:, :, None]
    cells = cell_histograms(np.ascontiguousarray(image), (8, 8), 9)
    expected = np.zeros((2, 2, 1, 9), np.float32)
    expected[:, :, 0, 0] = 6 * 7 * 8 / 64   # one border column per cell has gx = 0
    np.testing.assert_allclose(cells, expected, rtol=1e-6)


@pytest.mark.parametrize("norm", NORMS)
@pytest.mark.parametrize("cells_shape, cpb", [
    ((4, 6, 3, 9), (2, 2)),
    ((5, 5, 1, 12), (3, 3)),
    ((3, 7, 3, 7), (1, 1)),
    ((4, 6, 2, 9), (3, 2)),
    ((2, 2, 1, 9), (2, 2)),
])
def test_blocks_match_naive(norm, cells_shape, cpb):
    rng = np.random.default_rng(cells_shape[1])
    cells = (rng.random(cells_shape) * rng.choice([0.01, 1.0, 300.0], cells_shape)).astype(
        np.float32)
    cells[0, 0] = 0.0  # an all-zero cell
    actual = normalize_blocks(cells, cpb, norm)
    expected = naive_normalize_blocks(cells, cpb, norm)
    assert_close(actual, expected, f"{norm}")


@pytest.mark.parametrize("norm", NORMS)
def test_blocks_of_all_zero_cells_are_zero(norm):
    blocks = normalize_blocks(np.zeros((3, 3, 3, 9), np.float32), (2, 2), norm)
    assert blocks.shape == (2, 2, 3 * 4 * 9)
    assert np.all(blocks == 0.0)


# -- the float64 path: scikit-image's own computation --------------------------
#: float64 cells and blocks agree with scikit-image to float64 rounding (its
#: cell sums are float32, computed identically; the block norms' sums differ
#: only in order).
TOL_FLOAT64 = 1e-12


def float64_image(rng, shape):
    """Fractional values and a symmetric blurred disc: hundreds of gradients
    lie within a bit of a 45-degree boundary, where the bin depends on the
    last bit of NumPy's arctan2."""
    image = rng.random(shape)
    yy, xx = np.mgrid[:shape[0], :shape[1]]
    disc = ((yy - shape[0] / 2) ** 2 + (xx - shape[1] / 2) ** 2 < (min(shape[:2]) / 3) ** 2)
    blurred = cv2.GaussianBlur(disc.astype(np.float64) * 100, (0, 0), 2)
    image[:, :, 0] = blurred
    return image


@pytest.mark.parametrize("merge", [False, True])
@pytest.mark.parametrize("config", CONFIGS, ids=lambda c: f"{c[0][0]}x{c[0][1]}-ppc{c[1][0]}x"
                         f"{c[1][1]}-cpb{c[2][0]}-o{c[3]}")
@pytest.mark.parametrize("norm", NORMS)
def test_float64_matches_skimage_to_float64_rounding(norm, config, merge):
    (height, width), ppc, cpb, nbins = config
    image = float64_image(np.random.default_rng(height + width), (height + 40, width + 40, 3))
    cells = cell_histograms(image, ppc, nbins, merge_channels=merge)
    assert cells.dtype == np.float64
    blocks = normalize_blocks(cells, cpb, norm)
    assert blocks.dtype == np.float64
    hb, wb = blocks.shape[:2]
    if merge:
        expected = skimage_blocks(image, ppc, cpb, nbins, norm, channel_axis=-1)
        actual = blocks.reshape(expected.shape)
    else:
        expected = skimage_blocks(image[:, :, 0], ppc, cpb, nbins, norm)
        actual = blocks.reshape(hb, wb, 3, cpb[0], cpb[1], nbins)[:, :, 0]
    assert actual.shape == expected.shape
    assert float(np.max(np.abs(actual - expected))) < TOL_FLOAT64


def test_float64_cells_match_naive():
    image = float64_image(np.random.default_rng(1), (45, 61, 3))
    np.testing.assert_allclose(cell_histograms(image, (6, 8), 9),
                               naive_cell_histograms(image, (6, 8), 9), rtol=1e-6, atol=1e-6)


def test_float64_bands_give_the_same_cells(monkeypatch):
    # Large images are computed a band of cell rows at a time.
    from fastdet.kernels import hog_float64

    image = float64_image(np.random.default_rng(2), (83, 50, 3))
    whole = cell_histograms(image, (8, 8), 9, merge_channels=True)
    monkeypatch.setattr(hog_float64, "_BAND_PIXELS", 8 * 50 * 3 * 2)
    np.testing.assert_array_equal(cell_histograms(image, (8, 8), 9, merge_channels=True), whole)


@pytest.mark.parametrize("norm", NORMS)
def test_float64_blocks_match_naive(norm):
    rng = np.random.default_rng(4)
    cells = rng.random((5, 6, 2, 9)) * rng.choice([0.01, 1.0, 300.0], (5, 6, 2, 9))
    cells[0, 0] = 0.0
    np.testing.assert_allclose(normalize_blocks(cells, (2, 3), norm),
                               naive_normalize_blocks(cells, (2, 3), norm), rtol=0, atol=1e-13)


def test_float64_nan_and_inf_follow_skimage():
    image = np.random.default_rng(5).random((32, 32))
    image[5, 7] = np.nan
    image[20, 20] = np.inf
    with np.errstate(invalid="ignore"):  # scikit-image divides NaN blocks by NaN norms
        expected = skimage_hog(image, cells_per_block=(2, 2), feature_vector=False)
    actual = normalize_blocks(cell_histograms(image[:, :, None], (8, 8), 9), (2, 2), "L2-Hys")
    np.testing.assert_array_equal(np.isnan(actual.reshape(expected.shape)), np.isnan(expected))
    finite = ~np.isnan(expected)
    np.testing.assert_allclose(actual.reshape(expected.shape)[finite], expected[finite],
                               atol=TOL_FLOAT64)
