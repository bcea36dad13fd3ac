"""``score_window_rows``: the three parts of the window scores in one kernel call.

It must add exactly what the separate kernels add (the detector switched
from them to it), and, like them, match the naive references: normalised
blocks dotted with the weights, box-averaged pixels dotted with the spatial
weights, and window sums of the histogram tiles, all in float64.
"""

from __future__ import annotations

import numpy as np
import pytest

from fastdet.kernels.hog import to_phase_layout
from fastdet.kernels.score import (WindowRowScorer, add_hog_scores_from_phase_cells,
                                   add_spatial_scores, add_tile_window_sums, phase_scoring_pad,
                                   score_window_rows, window_count)
from naive import naive_normalize_blocks, naive_tile_window_sums, naive_window_sums

RTOL = 1e-4


def scale_maps(rng, rows_px, width_px, window, step_px, ppc, spatial_size):
    """Random cells (standard and phase layout), box image and tiles of one scale."""
    cells_y, cells_x = rows_px // ppc, width_px // ppc
    cells = rng.random((cells_y, cells_x, 3, 9), dtype=np.float32)
    cells[rng.random((cells_y, cells_x, 3)) < 0.1] = 0.0  # some empty cells
    step_cells = step_px // ppc
    phase = to_phase_layout(cells, step_cells, phase_scoring_pad(cells_x, step_cells, (2, 2)))
    factor = window // spatial_size
    box = rng.normal(size=(rows_px // factor, width_px // factor, 3)).astype(np.float32)
    tile = np.gcd(step_px, window)
    tiles = rng.normal(size=(rows_px // tile, width_px // tile)).astype(np.float32)
    return cells, phase, box, tiles, tile


def scale_inputs(seed, rows_px, width_px, window, step_px, ppc, spatial_size):
    """:func:`scale_maps` plus random HOG and spatial weights, the grid and the box factor."""
    rng = np.random.default_rng(seed)
    cells, phase, box, tiles, tile = scale_maps(rng, rows_px, width_px, window, step_px, ppc,
                                                spatial_size)
    n = window // ppc - 1
    hog_weights = rng.normal(size=(n, n, 2 * 2 * 3 * 9)).astype(np.float32)
    spatial_weights = rng.normal(size=(spatial_size, spatial_size, 3)).astype(np.float32)
    grid = (window_count(rows_px, window, step_px), window_count(width_px, window, step_px))
    return (cells, phase, box, tiles, tile, hog_weights, spatial_weights, grid,
            window // spatial_size)


# (scaled rows, scaled width, window, step in pixels, pixels per cell, spatial size)
SCALES = [
    (128, 200, 64, 16, 8, 32),    # the detector's step at its windows
    (136, 264, 64, 32, 8, 16),
    (96, 136, 64, 8, 8, 32),      # a step of one cell
    (72, 72, 64, 8, 8, 32),       # two windows each way
    (232, 88, 64, 48, 8, 8),      # odd step in cells, one window per row
]


@pytest.mark.parametrize("rows_px, width_px, window, step_px, ppc, spatial_size", SCALES)
@pytest.mark.parametrize("parts", ["all", "hog", "spatial", "tiles", "colour"])
def test_score_window_rows_adds_what_the_separate_kernels_add(rows_px, width_px, window,
                                                              step_px, ppc, spatial_size, parts):
    (cells, phase, box, tiles, tile, hog_weights, spatial_weights, grid,
     factor) = scale_inputs(rows_px + width_px + step_px, rows_px, width_px, window, step_px,
                            ppc, spatial_size)
    step_cells = step_px // ppc
    use = {"all": "hst", "hog": "h", "spatial": "s", "tiles": "t", "colour": "st"}[parts]
    bias = np.float32(-0.25)
    for first, stop in [(0, grid[0]), (grid[0] // 2, grid[0]), (1, 2), (0, 1)]:
        if first >= stop:
            continue
        fused = np.full(grid, bias, np.float32)
        score_window_rows(fused, (first, stop), window, step_px,
                          hog=(phase.copy(), cells.shape[1], (2, 2), "L2-Hys", hog_weights,
                               step_cells) if "h" in use else None,
                          spatial=(box, spatial_weights) if "s" in use else None,
                          tiles=(tiles, tile) if "t" in use else None)
        separate = np.full(grid, bias, np.float32)
        band = separate[first:stop]
        top, bottom = first * step_px, (stop - 1) * step_px + window
        if "h" in use:
            add_hog_scores_from_phase_cells(phase.copy(), cells.shape[1], (2, 2), "L2-Hys",
                                            hog_weights, step_cells, separate,
                                            window_rows=(first, stop))
        if "s" in use:
            add_spatial_scores(box[top // factor:bottom // factor], spatial_weights,
                               step_px // factor, band)
        if "t" in use:
            add_tile_window_sums(tiles[top // tile:bottom // tile], window // tile,
                                 step_px // tile, band)
        np.testing.assert_array_equal(fused, separate)
        # Window rows outside the band keep their value.
        assert np.all(fused[:first] == bias) and np.all(fused[stop:] == bias)


@pytest.mark.parametrize("rows_px, width_px, window, step_px, ppc, spatial_size", SCALES)
def test_score_window_rows_match_the_naive_references(rows_px, width_px, window, step_px, ppc,
                                                       spatial_size):
    (cells, phase, box, tiles, tile, hog_weights, spatial_weights, grid,
     factor) = scale_inputs(7 * rows_px + width_px, rows_px, width_px, window, step_px, ppc,
                            spatial_size)
    step_cells = step_px // ppc
    scores = np.zeros(grid, np.float32)
    score_window_rows(scores, (0, grid[0]), window, step_px,
                      hog=(phase, cells.shape[1], (2, 2), "L2-Hys", hog_weights, step_cells),
                      spatial=(box, spatial_weights), tiles=(tiles, tile))
    blocks = naive_normalize_blocks(cells.astype(np.float64), (2, 2), "L2-Hys")
    hog_part = naive_window_sums(blocks, hog_weights, step_cells, grid)
    spatial_part = naive_window_sums(box, spatial_weights, step_px // factor, grid)
    tile_part = naive_tile_window_sums(tiles, window // tile, step_px // tile, grid)
    expected = hog_part + spatial_part + tile_part
    # Relative to the size of the summed terms: a score near zero is a
    # difference of large ones.
    terms = (np.abs(blocks).sum() * np.abs(hog_weights).max() + np.abs(box).sum()
             * np.abs(spatial_weights).max() + np.abs(tiles).sum()) / (grid[0] * grid[1])
    np.testing.assert_allclose(scores, expected, rtol=RTOL, atol=RTOL * terms)


def test_score_window_rows_of_an_empty_band_change_nothing():
    scores = np.ones((3, 4), np.float32)
    box = np.ones((48, 56, 3), np.float32)
    score_window_rows(scores, (2, 2), 64, 16, spatial=(box, np.ones((32, 32, 3), np.float32)))
    score_window_rows(scores, (5, 9), 64, 16, spatial=(box, np.ones((32, 32, 3), np.float32)))
    np.testing.assert_array_equal(scores, 1.0)


def test_score_window_rows_reject_maps_too_small_for_the_windows():
    scores = np.zeros((4, 4), np.float32)
    with pytest.raises(ValueError, match="do not fit"):
        score_window_rows(scores, (0, 4), 64, 16, tiles=(np.zeros((6, 7), np.float32), 16))
    with pytest.raises(ValueError, match="do not fit"):
        score_window_rows(scores, (0, 4), 64, 16,
                          spatial=(np.zeros((20, 60, 3), np.float32),
                                   np.zeros((32, 32, 3), np.float32)))
    with pytest.raises(ValueError, match="C-contiguous float32"):
        score_window_rows(np.zeros((4, 4)), (0, 4), 64, 16)


def test_a_bound_scorer_adds_what_the_function_adds_and_checks_the_grid():
    (cells, phase, box, tiles, tile, hog_weights, spatial_weights, grid,
     _) = scale_inputs(3, 128, 200, 64, 16, 8, 32)
    hog = (phase, cells.shape[1], (2, 2), "L2-Hys", hog_weights, 2)
    spatial = (box, spatial_weights)
    bound = WindowRowScorer(grid, 64, 16, hog, spatial, (tiles, tile))
    for first, stop in [(0, grid[0]), (1, 3), (2, 99)]:
        by_function = np.zeros(grid, np.float32)
        score_window_rows(by_function, (first, stop), 64, 16, hog, spatial, (tiles, tile))
        by_bound = np.zeros(grid, np.float32)
        bound(by_bound, first, stop)
        np.testing.assert_array_equal(by_bound, by_function)
        assert np.any(by_bound[first:stop] != 0)
    with pytest.raises(ValueError, match="made for"):
        bound(np.zeros((grid[0] + 1, grid[1]), np.float32), 0, 1)
    with pytest.raises(ValueError, match="C-contiguous float32"):
        bound(np.zeros(grid, np.float64), 0, 1)
