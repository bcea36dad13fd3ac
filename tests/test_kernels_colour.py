"""``fastdet.kernels.colour.colour_maps`` against plain numpy.

The box mean must match ``float32(sum of bytes) * float32(1 / factor**2)``
bit for bit; the tile sums must match a float64 sum of the per-pixel weights to
float32 rounding, i.e. within 1e-5 of the tile's sum of absolute weights (one
wrong pixel in a tile is off by about 1 / (3 * tile**2) of it).

Shapes are chosen to hit every code path: whole 16-pixel box blocks plus
leftover pixels for factors 1, 2 and 4, the per-pixel box path (factor 3), the
four-pixel tile path (tile a multiple of 4) and the per-pixel one (other
tiles), images smaller than a tile or a box cell, and tile rows and box rows
that end at different image rows.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from fastdet.kernels.colour import _colour_maps, colour_maps


def reference_tiles(image, lut, tile):
    """float64 tile sums of sum_c lut[c, v_c] and of sum_c |lut[c, v_c]|."""
    lut = np.asarray(lut, np.float64)
    channels = [image[..., c] for c in range(3)]
    weight = sum(lut[c][channels[c]] for c in range(3))
    magnitude = sum(np.abs(lut[c])[channels[c]] for c in range(3))
    th, tw = image.shape[0] // tile, image.shape[1] // tile

    def sums(per_pixel):
        return per_pixel[:th * tile, :tw * tile].reshape(th, tile, tw, tile).sum(axis=(1, 3))

    return sums(weight), sums(magnitude)


def reference_box(image, factor):
    """float32(sum of each factor x factor cell) * float32(1 / factor**2)."""
    bh, bw = image.shape[0] // factor, image.shape[1] // factor
    cells = image[:bh * factor, :bw * factor].astype(np.int64)
    sums = cells.reshape(bh, factor, bw, factor, 3).sum(axis=(1, 3))
    return sums.astype(np.float32) * np.float32(1.0 / (factor * factor))


def check(image, lut, tile, factor):
    tiles, box = colour_maps(image, lut, tile, factor)
    assert tiles.dtype == np.float32 and box.dtype == np.float32
    if lut is None:
        assert tiles.shape == (0, 0)
    else:
        expected, magnitude = reference_tiles(image, lut, tile)
        assert tiles.shape == expected.shape
        np.testing.assert_array_less(np.abs(tiles - expected), 1e-5 * magnitude + 1e-30)
    if factor == 0:
        assert box.shape == (0, 0, 3)
    else:
        np.testing.assert_array_equal(box, reference_box(image, factor))
    return tiles, box


def random_lut(rng):
    return rng.normal(size=(3, 256)).astype(np.float32)


SHAPES = [
    (1, 1), (3, 5), (7, 15),          # smaller than a tile (and some than a box cell)
    (8, 8), (16, 16),                 # exactly one tile of 8 / of 16
    (17, 33), (31, 47),               # odd: partial tiles and cells everywhere
    (24, 107),                        # factor 2: 3 whole blocks + 5 pixels per row
    (45, 143),                        # factor 4: 2 whole blocks + 3 pixels per row
    (50, 71),                         # factor 1: 4 whole blocks + 7 pixels per row
    (67, 200),
]


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("tile, factor", [
    (8, 2), (16, 2), (8, 4), (16, 1), (8, 0), (16, 4), (32, 2),
    (4, 2), (12, 3), (5, 2), (6, 1), (1, 4),
])
def test_random_images_match_numpy(shape, tile, factor):
    rng = np.random.default_rng(shape[0] * 1000 + shape[1] + tile * 7 + factor)
    image = rng.integers(0, 256, shape + (3,), dtype=np.uint8)
    check(image, random_lut(rng), tile, factor)


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("factor", [1, 2, 3, 4])
def test_box_alone_matches_numpy(shape, factor):
    rng = np.random.default_rng(shape[0] + shape[1] * 31 + factor)
    image = rng.integers(0, 256, shape + (3,), dtype=np.uint8)
    check(image, None, 8, factor)


def test_extreme_values():
    """All-255 pixels (largest sums) and all-0 pixels, next to each other."""
    image = np.zeros((40, 96, 3), np.uint8)
    image[:, 48:] = 255
    image[::3, ::5, 1] = 255
    lut = np.linspace(-1e3, 1e3, 768, dtype=np.float32).reshape(3, 256)
    for tile, factor in [(8, 2), (16, 4), (8, 1), (5, 3)]:
        check(image, lut, tile, factor)


def test_each_output_is_independent_of_the_other():
    """Tile sums and box mean computed together equal each computed alone
    (the two passes are interleaved by bands of rows)."""
    rng = np.random.default_rng(7)
    lut = random_lut(rng)
    for shape in [(37, 131), (9, 70), (70, 9), (100, 64)]:
        image = rng.integers(0, 256, shape + (3,), dtype=np.uint8)
        for tile, factor in [(8, 2), (16, 2), (8, 4), (32, 1), (16, 3), (5, 2)]:
            tiles, box = colour_maps(image, lut, tile, factor)
            np.testing.assert_array_equal(tiles, colour_maps(image, lut, tile, 0)[0])
            np.testing.assert_array_equal(box, colour_maps(image, None, tile, factor)[1])


def test_non_contiguous_image_and_lut():
    rng = np.random.default_rng(3)
    big = rng.integers(0, 256, (80, 150, 3), dtype=np.uint8)
    view = big[5:70:2, 3:140]                       # strided rows
    lut_view = rng.normal(size=(256, 3)).astype(np.float32).T   # Fortran-ordered (3, 256)
    assert not view.flags.c_contiguous and not lut_view.flags.c_contiguous
    check(view, lut_view, 8, 2)
    check(view, lut_view.astype(np.float64), 16, 4)   # float64 LUT is converted


def test_lut_none_and_factor_zero_skip_both():
    image = np.full((16, 16, 3), 9, np.uint8)
    tiles, box = colour_maps(image, None, 8, 0)
    assert tiles.shape == (0, 0) and box.shape == (0, 0, 3)


def test_tile_sums_read_the_right_pixel_and_channel():
    """One marked pixel per tile, at a random place and channel: its weight
    (unique per channel and value, exact in float32) lands in its tile only."""
    tile = 8
    th, tw = 5, 9
    image = np.zeros((th * tile + 3, tw * tile + 5, 3), np.uint8)
    lut = (np.arange(768, dtype=np.float32) + 1).reshape(3, 256)
    lut[:, 0] = 0                                   # unmarked pixels weigh 0
    expected = np.zeros((th, tw), np.float32)
    rng = np.random.default_rng(11)
    for ty in range(th):
        for tx in range(tw):
            dy, dx, c = rng.integers(0, tile), rng.integers(0, tile), rng.integers(0, 3)
            value = rng.integers(1, 256)
            image[ty * tile + dy, tx * tile + dx, c] = value
            expected[ty, tx] = lut[c, value]
    for factor in (0, 2):
        np.testing.assert_array_equal(colour_maps(image, lut, tile, factor)[0], expected)


@pytest.mark.parametrize("shape", [(1, 1), (7, 15), (17, 33), (45, 143), (67, 200)])
@pytest.mark.parametrize("tile, factor", [(8, 2), (16, 4), (8, 1), (5, 3), (12, 2), (32, 0)])
def test_kernel_writes_every_output_element(shape, tile, factor):
    """colour_maps hands the kernel uninitialised (np.empty) outputs, so the
    kernel must write every element: start from NaN and look for leftovers."""
    rng = np.random.default_rng(shape[1] + tile)
    image = rng.integers(0, 256, shape + (3,), dtype=np.uint8)
    lut = random_lut(rng)
    tiles = np.full((shape[0] // tile, shape[1] // tile), np.nan, np.float32)
    box = np.full((shape[0] // factor, shape[1] // factor, 3) if factor else (0, 0, 3), np.nan,
                  np.float32)
    _colour_maps(image, lut, tile, factor, True, factor > 0, tiles, box)
    assert not np.isnan(tiles).any() and not np.isnan(box).any()
    expected_tiles, expected_box = check(image, lut, tile, factor)
    np.testing.assert_array_equal(tiles, expected_tiles)
    np.testing.assert_array_equal(box, expected_box)


@pytest.fixture(scope="module")
def real_hls(data_dir):
    frame = cv2.imread(str(data_dir / "test_images" / "test1.jpg"))
    assert frame is not None, "test_images/test1.jpg is unreadable"
    return cv2.cvtColor(frame, cv2.COLOR_BGR2HLS)


@pytest.mark.parametrize("size, rows", [
    ((1697, 225), (360, 540)),
    ((417, 225), (360, 660)),
    ((721, 145), (380, 525)),
    ((640, 129), (400, 529)),
    ((99, 37), (400, 500)),
])
@pytest.mark.parametrize("tile, factor", [(8, 2), (16, 2), (32, 4), (8, 1)])
def test_real_image_matches_numpy(real_hls, size, rows, tile, factor):
    """The detector's use: HLS crops resized to each search scale."""
    image = cv2.resize(real_hls[rows[0]:rows[1]], size)
    # The detector's LUT: per-channel bin weights expanded to all 256 values.
    bin_weights = np.random.default_rng(0).normal(size=(3, 32)).astype(np.float32)
    lut = np.ascontiguousarray(bin_weights[:, np.arange(256) * 32 // 256])
    check(image, lut, tile, factor)
