"""Tests for the window-scoring kernels of ``fastdet.kernels.score`` and for
``fastdet.kernels.colour.colour_maps``, against explicit per-window
slicing + ``np.dot`` / ``np.sum`` in float64 (``naive.py``)."""

from __future__ import annotations

import functools
import sys
from pathlib import Path

import numpy as np
import pytest

from fastdet.kernels.colour import colour_maps
from fastdet.kernels.score import (add_hog_scores, add_spatial_scores, add_tile_window_sums,
                                   window_count)
from naive import (naive_tile_weight_sums, naive_tile_window_sums, naive_window_sums)

# benchmarks/ (not an installed package) holds the walks that compare block forms.
ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

RTOL = 1e-4


def assert_scores_close(actual, expected, terms):
    """``actual`` float32 == ``expected`` float64 to RTOL, relative to the
    size of the summed terms (a score near zero is a difference of large
    terms, so its error scales with them, not with it)."""
    assert actual.dtype == np.float32
    assert actual.shape == expected.shape
    np.testing.assert_allclose(actual, expected, rtol=RTOL, atol=RTOL * max(terms, 1e-30))


def grid_of(map_shape, window, step):
    return (window_count(map_shape[0], window, step), window_count(map_shape[1], window, step))


# -- window_count -------------------------------------------------------------
@pytest.mark.parametrize("length, window, step, expected", [
    (0, 1, 1, 0), (7, 8, 1, 0), (8, 8, 1, 1), (8, 8, 5, 1), (9, 8, 1, 2), (9, 8, 2, 1),
    (10, 8, 2, 2), (23, 7, 4, 5), (24, 7, 4, 5), (25, 7, 4, 5), (26, 7, 4, 5), (27, 7, 4, 6),
])
def test_window_count(length, window, step, expected):
    assert window_count(length, window, step) == expected
    # Brute force: origins o = 0, step, ... with o + window <= length.
    assert expected == len([o for o in range(0, length + 1, step) if o + window <= length])


# -- HOG ----------------------------------------------------------------------
def random_blocks(rng, shape):
    return rng.random(shape, dtype=np.float32)


@pytest.mark.parametrize("parallel", [False, True])
@pytest.mark.parametrize("map_shape, n, features, step", [
    ((23, 37), 7, 36, 1),
    ((23, 37), 7, 36, 2),
    ((23, 37), 7, 36, 3),
    ((31, 29), 5, 108, 4),
    ((19, 44), 3, 12, 5),
    ((9, 13), 1, 9, 1),
    ((9, 13), 1, 9, 3),
    ((7, 7), 7, 36, 1),         # exactly one window
    ((7, 7), 7, 36, 6),         # one window, whatever the step
    ((6, 40), 7, 36, 2),        # 0 window rows
    ((40, 6), 7, 36, 2),        # 0 window columns
    ((5, 5), 7, 36, 1),         # 0 windows
])
def test_add_hog_scores_matches_naive(parallel, map_shape, n, features, step):
    rng = np.random.default_rng(map_shape[0] * 100 + step)
    blocks = random_blocks(rng, map_shape + (features,))
    weights = rng.normal(size=(n, n, features)).astype(np.float32)
    grid = grid_of(map_shape, n, step)
    start = rng.normal(size=grid).astype(np.float32)
    out = start.copy()
    add_hog_scores(blocks, weights, step, out, parallel=parallel)
    expected = start.astype(np.float64) + naive_window_sums(blocks, weights, step, grid)
    assert_scores_close(out, expected, np.abs(weights).sum())


@pytest.mark.parametrize("parallel", [False, True])
def test_add_hog_scores_on_a_partial_grid(parallel):
    # A grid smaller than what fits scores the top-left windows only.
    rng = np.random.default_rng(1)
    blocks = random_blocks(rng, (20, 30, 36))
    weights = rng.normal(size=(7, 7, 36)).astype(np.float32)
    out = np.zeros((3, 4), np.float32)
    add_hog_scores(blocks, weights, 2, out, parallel=parallel)
    assert_scores_close(out, naive_window_sums(blocks, weights, 2, (3, 4)),
                        np.abs(weights).sum())


@pytest.mark.parametrize("parallel", [False, True])
def test_hog_scores_pick_the_right_window(parallel):
    # One non-zero block: only the windows that contain it score, with the
    # weight at its position within each window.
    n, features, step = 3, 4, 2
    blocks = np.zeros((9, 11, features), np.float32)
    blocks[4, 6, 2] = 1.0
    weights = np.arange(n * n * features, dtype=np.float32).reshape(n, n, features) + 1
    grid = grid_of(blocks.shape, n, step)
    out = np.zeros(grid, np.float32)
    add_hog_scores(blocks, weights, step, out, parallel=parallel)
    expected = np.zeros(grid, np.float32)
    for iy in range(grid[0]):
        for ix in range(grid[1]):
            dy, dx = 4 - iy * step, 6 - ix * step
            if 0 <= dy < n and 0 <= dx < n:
                expected[iy, ix] = weights[dy, dx, 2]
    np.testing.assert_array_equal(out, expected)
    assert np.count_nonzero(out) == 4


# -- spatial ------------------------------------------------------------------
@pytest.mark.parametrize("parallel", [False, True])
@pytest.mark.parametrize("map_shape, size, step", [
    ((45, 71), 32, 4),
    ((45, 71), 32, 13),
    ((37, 29), 16, 1),
    ((37, 29), 16, 3),
    ((33, 50), 8, 5),
    ((32, 32), 32, 8),          # exactly one window
    ((31, 90), 32, 4),          # 0 window rows
    ((90, 31), 32, 4),          # 0 window columns
    ((10, 10), 32, 4),          # 0 windows
])
def test_add_spatial_scores_matches_naive(parallel, map_shape, size, step):
    rng = np.random.default_rng(map_shape[1] * 10 + step)
    spatial = rng.integers(0, 256, map_shape + (3,)).astype(np.float32)
    weights = rng.normal(scale=0.01, size=(size, size, 3)).astype(np.float32)
    grid = grid_of(map_shape, size, step)
    start = rng.normal(size=grid).astype(np.float32)
    out = start.copy()
    add_spatial_scores(spatial, weights, step, out, parallel=parallel)
    expected = start.astype(np.float64) + naive_window_sums(spatial, weights, step, grid)
    assert_scores_close(out, expected, 255 * np.abs(weights).sum())


@pytest.mark.parametrize("windows", [1, 3, 4])
def test_the_spatial_rows_block_gives_the_general_blocks_bits(windows):
    """The block for the default spatial rows (96 elements) writes each row's
    products out in full; each window's sum must keep the general block's
    order, bit for bit (windows 1-4 a call, a last call with fewer)."""
    from benchmarks.bench_kernels import spatial_grid_walk
    from fastdet.kernels.score import SPATIAL_ROW

    rng = np.random.default_rng(windows)
    image = rng.normal(size=(70, 61 * 3 + SPATIAL_ROW)).astype(np.float32)
    weights = rng.normal(size=(32, SPATIAL_ROW)).astype(np.float32)
    grids = []
    for fixed in (False, True):
        out = np.zeros((5, 23), np.float32)
        spatial_grid_walk(fixed, windows)(image, weights, 9, 6, out)
        grids.append(out)
    np.testing.assert_array_equal(grids[1], grids[0])
    expected = np.array([[np.dot(image[iy * 9:iy * 9 + 32, ix * 6:ix * 6 + SPATIAL_ROW].ravel()
                                 .astype(np.float64), weights.ravel().astype(np.float64))
                          for ix in range(23)] for iy in range(5)])
    assert_scores_close(grids[1], expected, np.abs(weights).sum() * 4)


@pytest.mark.parametrize("parallel", [False, True])
def test_a_windows_spatial_score_does_not_depend_on_its_neighbours(parallel):
    # Windows are dotted several at a time; shifting the map by three windows
    # regroups them, and each window's sum must stay the same bits.
    rng = np.random.default_rng(3)
    spatial = rng.random((40, 130, 3), dtype=np.float32) * 255
    weights = rng.normal(scale=0.01, size=(16, 16, 3)).astype(np.float32)
    step = 2
    whole = np.zeros(grid_of(spatial.shape, 16, step), np.float32)
    add_spatial_scores(spatial, weights, step, whole, parallel=parallel)
    shifted_map = np.ascontiguousarray(spatial[:, 3 * step:])
    shifted = np.zeros(grid_of(shifted_map.shape, 16, step), np.float32)
    add_spatial_scores(shifted_map, weights, step, shifted, parallel=parallel)
    np.testing.assert_array_equal(shifted, whole[:, 3:3 + shifted.shape[1]])


def test_scores_add_up():
    # The kernels add into ``out``: HOG then spatial == their sum.
    rng = np.random.default_rng(2)
    blocks = random_blocks(rng, (15, 23, 36))
    hog_w = rng.normal(size=(7, 7, 36)).astype(np.float32)
    spatial = rng.random((64, 96, 3), dtype=np.float32) * 255
    spatial_w = rng.normal(scale=0.01, size=(32, 32, 3)).astype(np.float32)
    grid = grid_of(blocks.shape, 7, 2)  # step 2 cells = 16 px = 8 spatial px
    assert grid == grid_of(spatial.shape, 32, 8)
    out = np.full(grid, -1.5, np.float32)
    add_hog_scores(blocks, hog_w, 2, out)
    add_spatial_scores(spatial, spatial_w, 8, out)
    expected = (-1.5 + naive_window_sums(blocks, hog_w, 2, grid)
                + naive_window_sums(spatial, spatial_w, 8, grid))
    assert_scores_close(out, expected, np.abs(hog_w).sum() + 255 * np.abs(spatial_w).sum())


# -- colour-histogram tiles -------------------------------------------------
@pytest.mark.parametrize("shape, tile", [
    ((67, 45, 3), 8),
    ((67, 45, 3), 16),
    ((64, 64, 3), 64),
    ((63, 64, 3), 64),          # no whole tile
    ((37, 53, 3), 5),
    ((9, 130, 3), 1),
    ((5, 5, 3), 7),             # no whole tile
])
def test_tile_weight_sums_matches_naive(shape, tile):
    rng = np.random.default_rng(shape[0] + tile)
    image = rng.integers(0, 256, shape, dtype=np.uint8)
    lut = rng.normal(size=(shape[2], 256)).astype(np.float32)
    actual = colour_maps(image, lut, tile)[0]
    expected = naive_tile_weight_sums(image, lut, tile)
    assert actual.dtype == np.float32
    assert actual.shape == (shape[0] // tile, shape[1] // tile)
    np.testing.assert_allclose(actual, expected, rtol=RTOL,
                               atol=RTOL * tile * tile * np.abs(lut).max(initial=1.0) * shape[2])


def test_tile_weight_sums_reads_each_channel_with_its_own_lut():
    image = np.zeros((4, 4, 3), np.uint8)
    image[..., 0], image[..., 1], image[..., 2] = 10, 20, 30
    image[0, 0] = (255, 0, 1)
    lut = np.zeros((3, 256), np.float32)
    lut[0, 10], lut[1, 20], lut[2, 30] = 1.0, 100.0, 10000.0
    lut[0, 255], lut[1, 0], lut[2, 1] = 0.5, 0.25, 0.125
    out = colour_maps(image, lut, 2)[0]
    expected = np.full((2, 2), 4 * 10101.0, np.float32)
    expected[0, 0] = 3 * 10101.0 + 0.875
    np.testing.assert_array_equal(out, expected)


@pytest.mark.parametrize("tiles_shape, size, step", [
    ((23, 37), 4, 1),
    ((23, 37), 4, 3),
    ((23, 37), 8, 2),
    ((19, 21), 1, 1),
    ((19, 21), 2, 5),
    ((4, 4), 4, 1),             # exactly one window
    ((3, 30), 4, 1),            # 0 window rows
    ((30, 3), 4, 1),            # 0 window columns
    ((2, 2), 4, 2),             # 0 windows
])
def test_add_tile_window_sums_matches_naive(tiles_shape, size, step):
    rng = np.random.default_rng(tiles_shape[0] * size + step)
    tiles = rng.normal(size=tiles_shape).astype(np.float32) * 100
    grid = grid_of(tiles_shape, size, step)
    start = rng.normal(size=grid).astype(np.float32)
    out = start.copy()
    add_tile_window_sums(tiles, size, step, out)
    expected = start.astype(np.float64) + naive_tile_window_sums(tiles, size, step, grid)
    assert_scores_close(out, expected, size * size * 100 * 5)


@pytest.mark.parametrize("hist_bins", [32, 16, 7])
@pytest.mark.parametrize("step_px", [8, 16, 24, 48])
def test_histogram_part_equals_per_window_histograms(hist_bins, step_px):
    """tile sums + window sums of a per-value weight == weights . np.histogram
    of each window's pixels (what the detector relies on)."""
    rng = np.random.default_rng(hist_bins + step_px)
    window = 64
    image = rng.integers(0, 256, (141, 203, 3), dtype=np.uint8)
    hist_w = rng.normal(size=(3, hist_bins)).astype(np.float32)
    edges = np.arange(256) * hist_bins // 256               # value -> bin
    lut = np.ascontiguousarray(hist_w[:, edges])
    tile = int(np.gcd(step_px, window))
    grid = grid_of(image.shape, window, step_px)
    out = np.zeros(grid, np.float32)
    add_tile_window_sums(colour_maps(image, lut, tile)[0], window // tile, step_px // tile, out)
    expected = np.zeros(grid)
    for iy in range(grid[0]):
        for ix in range(grid[1]):
            pixels = image[iy * step_px:iy * step_px + window, ix * step_px:ix * step_px + window]
            for c in range(3):
                counts = np.bincount(edges[pixels[:, :, c].ravel()], minlength=hist_bins)
                expected[iy, ix] += np.dot(counts, hist_w[c].astype(np.float64))
    assert_scores_close(out, expected, window * window * 3 * np.abs(hist_w).max())


# -- grids that do not fit ------------------------------------------------
@pytest.mark.parametrize("extra", [(1, 0), (0, 1), (1, 1), (5, 0)])
@pytest.mark.parametrize("parallel", [False, True])
def test_hog_grid_that_does_not_fit_raises(extra, parallel):
    rng = np.random.default_rng(0)
    blocks = random_blocks(rng, (23, 37, 36))
    weights = np.ones((7, 7, 36), np.float32)
    ny, nx = grid_of(blocks.shape, 7, 3)
    out = np.zeros((ny + extra[0], nx + extra[1]), np.float32)
    with pytest.raises(ValueError):
        add_hog_scores(blocks, weights, 3, out, parallel=parallel)
    assert not out.any(), "a rejected grid must be left untouched"


@pytest.mark.parametrize("extra", [(1, 0), (0, 1)])
def test_spatial_grid_that_does_not_fit_raises(extra):
    spatial = np.ones((45, 71, 3), np.float32)
    weights = np.ones((32, 32, 3), np.float32)
    ny, nx = grid_of(spatial.shape, 32, 4)
    with pytest.raises(ValueError):
        add_spatial_scores(spatial, weights, 4, np.zeros((ny + extra[0], nx + extra[1]),
                                                         np.float32))


@pytest.mark.parametrize("extra", [(1, 0), (0, 1)])
def test_tile_grid_that_does_not_fit_raises(extra):
    tiles = np.ones((23, 37), np.float32)
    ny, nx = grid_of(tiles.shape, 8, 2)
    with pytest.raises(ValueError):
        add_tile_window_sums(tiles, 8, 2, np.zeros((ny + extra[0], nx + extra[1]), np.float32))


def test_window_larger_than_the_map_with_a_grid_raises():
    # A one-window grid on a map smaller than the window.
    with pytest.raises(ValueError):
        add_hog_scores(np.ones((5, 5, 4), np.float32), np.ones((7, 7, 4), np.float32), 1,
                       np.zeros((1, 1), np.float32))
    with pytest.raises(ValueError):
        add_tile_window_sums(np.ones((3, 3), np.float32), 4, 1, np.zeros((1, 1), np.float32))


@pytest.mark.parametrize("shape, factor", [
    ((64, 64, 3), 2), ((67, 45, 3), 2), ((67, 45, 3), 4), ((64, 64, 3), 1), ((3, 3, 3), 4),
    ((9, 130, 3), 3),
])
def test_colour_maps_box_mean_matches_numpy(shape, factor):
    rng = np.random.default_rng(shape[1] + factor)
    image = rng.integers(0, 256, shape, dtype=np.uint8)
    tiles, box = colour_maps(image, None, 8, factor)
    assert tiles.shape == (0, 0)
    h, w = shape[0] // factor, shape[1] // factor
    expected = image[:h * factor, :w * factor].astype(np.float64).reshape(
        h, factor, w, factor, 3).mean(axis=(1, 3))
    assert box.shape == (h, w, 3) and box.dtype == np.float32
    np.testing.assert_allclose(box, expected, rtol=1e-6, atol=1e-4)


def test_colour_maps_rejects_non_colour_images():
    with pytest.raises(ValueError, match="uint8"):
        colour_maps(np.zeros((8, 8), np.uint8), None, 8, 2)
    with pytest.raises(ValueError, match="uint8"):
        colour_maps(np.zeros((8, 8, 3), np.float32), None, 8, 2)


def test_the_spatial_rows_block_gives_the_same_bits_for_any_window_count():
    """_DOT_WINDOWS differs by CPU (four with AVX-512, three with AVX2): a
    window's sum must not depend on how many are dotted at once."""
    from benchmarks.bench_kernels import spatial_grid_walk
    from fastdet.kernels.score import SPATIAL_ROW

    rng = np.random.default_rng(11)
    image = rng.normal(size=(70, 61 * 3 + SPATIAL_ROW)).astype(np.float32)
    weights = rng.normal(size=(32, SPATIAL_ROW)).astype(np.float32)
    grids = []
    for windows in (1, 3, 4):
        out = np.zeros((5, 23), np.float32)
        spatial_grid_walk(True, windows)(image, weights, 9, 6, out)
        grids.append(out)
    for grid in grids[1:]:
        np.testing.assert_array_equal(grid, grids[0])


@functools.lru_cache(maxsize=None)
def _hog_dots_walk(rows, chunks):
    """Dots of one block row with ``rows`` window rows, ``chunks`` vectors of
    windows a call, over every vector of a row of ``stride`` positions."""
    from numba import njit

    from fastdet.kernels import score

    dots = score._window_dots(rows, chunks)
    lanes = score._LANES

    @njit
    def walk(weights, blocks, stride, second, channels, per_channel, acc):
        for chunk in range(0, stride, lanes * chunks):
            dots(weights, 0, channels * per_channel, blocks, stride, chunk, second, channels,
                 per_channel, acc, chunk, stride)

    return walk


@pytest.mark.parametrize("rows", [1, 2])
@pytest.mark.parametrize("per_channel", [36, 35])
def test_window_dots_side_by_side_give_each_windows_bits(rows, per_channel):
    """Two vectors of windows dotted side by side (the edge block rows' form)
    add exactly what one vector at a time adds."""
    channels, stride = 3, 64
    rng = np.random.default_rng(rows * 100 + per_channel)
    weights = rng.normal(size=rows * channels * per_channel).astype(np.float32)
    blocks = rng.normal(size=channels * per_channel * stride + 32).astype(np.float32)
    second = rng.random(channels * stride + 32).astype(np.float32)
    start = rng.normal(size=rows * stride + 32).astype(np.float32)
    sums = []
    for chunks in (1, 2):
        acc = start.copy()
        _hog_dots_walk(rows, chunks)(weights, blocks, stride, second, channels, per_channel,
                                     acc)
        sums.append(acc)
    np.testing.assert_array_equal(sums[1], sums[0])
    # And they are the dot products (float64 reference, float32 tolerance).
    for i in range(rows):
        w = weights[i * channels * per_channel:(i + 1) * channels * per_channel]
        feats = blocks[:channels * per_channel * stride].reshape(channels * per_channel,
                                                                 stride).astype(np.float64)
        per_c = (w.astype(np.float64)[:, None] * feats).reshape(channels, per_channel,
                                                                stride).sum(axis=1)
        expected = start[i * stride:(i + 1) * stride] + (
            per_c * second[:channels * stride].reshape(channels, stride)).sum(axis=0)
        np.testing.assert_allclose(sums[0][i * stride:(i + 1) * stride], expected,
                                   rtol=1e-4, atol=1e-3)


@functools.lru_cache(maxsize=None)
def _normalise_walk(copies):
    """L2-Hys normalisation of one block row, ``copies`` vectors of positions a call."""
    from numba import njit, uint64

    from fastdet.kernels import score

    normalise = score._normalise_blocks(3, copies)
    lanes = score._LANES

    @njit
    def walk(cells, energy, k, length, normalised, stride, second, eps_sq):
        for p0 in range(0, stride, lanes * copies):
            normalise(cells, uint64(0), uint64(9 * length), uint64(length), uint64(k),
                      uint64(2), uint64(2), uint64(9), energy, uint64(0), uint64(length),
                      uint64(p0), eps_sq, eps_sq, normalised, uint64(0), uint64(stride), second,
                      uint64(0))

    return walk


def test_l2_hys_side_by_side_gives_each_blocks_bits():
    """Two vectors of block positions normalised side by side (the scorer's
    form) give exactly what one vector at a time gives."""
    k, stride = 40, 64                    # positions of a phase; a row of whole vectors
    length = 2 * k + stride               # room for the cells a block reads past p0
    rng = np.random.default_rng(8)
    cells = rng.random(2 * 9 * length).astype(np.float32)
    energy = (cells.reshape(2, 9, length) ** 2).sum(axis=1).ravel().astype(np.float32)
    eps_sq = np.float32(1e-10)
    results = []
    for copies in (1, 2):
        normalised = np.full(36 * stride + 16, np.nan, np.float32)
        second = np.full(stride + 16, np.nan, np.float32)
        _normalise_walk(copies)(cells, energy, k, length, normalised, stride, second, eps_sq)
        results.append((normalised[:36 * stride], second[:stride]))
    for one, two in zip(*results):
        np.testing.assert_array_equal(two, one)
    assert np.isfinite(results[0][0]).all() and (results[0][0] <= np.float32(0.2)).all()
