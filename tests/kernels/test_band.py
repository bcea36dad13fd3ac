"""``BandScorer``: a scale's cells, colour maps and window scores in one kernel call.

The detector switched from three bound calls per scale to it: it must
compute exactly what those three compute, into the same arrays, for any
band of window rows, and the scores must match the naive references (cells,
blocks, box means and tile sums in float64) whatever the calls.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from fastdet.kernels import band as band_module
from fastdet.kernels.band import STAGES, BandScorer
from fastdet.kernels.colour import ColourMapRows
from fastdet.kernels.hog import PhaseCellRows, phase_layout_shape
from fastdet.kernels.score import WindowRowScorer, phase_scoring_pad, window_count
from naive import (naive_cell_histograms, naive_normalize_blocks, naive_tile_weight_sums,
                   naive_tile_window_sums, naive_window_sums)

WINDOW, PPC, SPATIAL = 64, 8, 32


class Scale:
    """One scale's arrays and bound calls, as ``fastdet.detector.scoring._ScaleWork`` makes them."""

    def __init__(self, height, width, step_px, seed):
        rng = np.random.default_rng(seed)
        self.image = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
        self.step_px = step_px
        step_cells = step_px // PPC
        cells_y, cells_x = height // PPC, width // PPC
        self.grid = (window_count(height, WINDOW, step_px), window_count(width, WINDOW, step_px))
        pad = phase_scoring_pad(cells_x, step_cells, (2, 2))
        self.cells = np.zeros(phase_layout_shape(cells_y, cells_x, 3, 9, step_cells, pad),
                              np.float32)
        self.cell_rows = PhaseCellRows(self.image.shape, (PPC, PPC), 9, self.cells, step_cells,
                                       pad)
        n = WINDOW // PPC - 1
        self.hog_weights = rng.normal(size=(n, n, 2 * 2 * 3 * 9)).astype(np.float32)
        self.spatial_weights = rng.normal(size=(SPATIAL, SPATIAL, 3)).astype(np.float32)
        self.lut = rng.normal(size=(3, 256)).astype(np.float32)
        self.tile, self.factor = int(np.gcd(step_px, WINDOW)), WINDOW // SPATIAL
        self.covered = (self.grid[0] - 1) * step_px + WINDOW
        self.tiles = np.zeros((self.covered // self.tile, width // self.tile), np.float32)
        self.box = np.zeros((self.covered // self.factor, width // self.factor, 3), np.float32)
        self.colour_rows = ColourMapRows((self.covered, width, 3), self.lut, self.tile,
                                         self.factor, (self.tiles, self.box))
        self.windows = WindowRowScorer(
            self.grid, WINDOW, step_px,
            (self.cells, cells_x, (2, 2), "L2-Hys", self.hog_weights, step_cells),
            (self.box, self.spatial_weights), (self.tiles, self.tile))
        self.scores = np.full(self.grid, np.float32(-0.5), np.float32)

    def rows(self, first, stop):
        """Pixel rows window rows ``first`` .. ``stop - 1`` cover."""
        return first * self.step_px, (stop - 1) * self.step_px + WINDOW

    def three_calls(self, first, stop):
        top, bottom = self.rows(first, stop)
        self.cell_rows(self.image, top // PPC, bottom // PPC)
        self.colour_rows(self.image[:self.covered], top, bottom)
        self.windows(self.scores, first, stop)

    def one_call(self, first, stop):
        top, bottom = self.rows(first, stop)
        band = BandScorer(self.cell_rows, self.colour_rows, self.windows)
        return band(self.image, self.image[:self.covered], top, bottom, first, stop,
                    self.scores)


# (scaled rows, scaled width, window step in pixels): the default search's
# steps of 2 and 4 cells, and one of a single cell; even cell columns.
SCALES = [(113, 1280, 16), (129, 400, 32), (97, 208, 16), (72, 96, 8), (200, 144, 16)]


def window_bands(rows):
    return sorted({(0, rows), (rows // 2, rows), (0, 1), (rows - 1, rows)} - {(0, 0)})


@pytest.mark.parametrize("height, width, step_px", SCALES)
def test_one_call_computes_what_the_three_calls_compute(height, width, step_px):
    for first, stop in window_bands(window_count(height, WINDOW, step_px)):
        one, three = (Scale(height, width, step_px, seed=height + width) for _ in range(2))
        one.one_call(first, stop)
        three.three_calls(first, stop)
        for name in ("cells", "tiles", "box", "scores"):
            np.testing.assert_array_equal(getattr(one, name), getattr(three, name),
                                          err_msg=f"{name}, window rows {first}..{stop}")
        # Window rows outside the band keep their value.
        assert np.all(one.scores[:first] == -0.5) and np.all(one.scores[stop:] == -0.5)


@pytest.mark.parametrize("height, width, step_px", SCALES)
def test_one_call_scores_match_the_naive_references(height, width, step_px):
    scale = Scale(height, width, step_px, seed=3 * height + width)
    scale.one_call(0, scale.grid[0])
    cells = naive_cell_histograms(scale.image, (PPC, PPC), 9)
    blocks = naive_normalize_blocks(cells, (2, 2), "L2-Hys")
    covered = scale.image[:scale.covered].astype(np.float64)
    f = scale.factor
    box = covered.reshape(covered.shape[0] // f, f, covered.shape[1] // f, f, 3).mean(axis=(1, 3))
    tiles = naive_tile_weight_sums(scale.image[:scale.covered], scale.lut, scale.tile)
    expected = (-0.5 + naive_window_sums(blocks, scale.hog_weights, step_px // PPC, scale.grid)
                + naive_window_sums(box, scale.spatial_weights, step_px // f, scale.grid)
                + naive_tile_window_sums(tiles, WINDOW // scale.tile, step_px // scale.tile,
                                         scale.grid))
    # Relative to the size of the summed terms: a score near zero is a
    # difference of large ones.
    terms = (np.abs(blocks).sum() * np.abs(scale.hog_weights).max()
             + np.abs(box).sum() * np.abs(scale.spatial_weights).max()
             + np.abs(tiles).sum()) / (scale.grid[0] * scale.grid[1])
    np.testing.assert_allclose(scale.scores, expected, rtol=1e-4, atol=1e-4 * terms)


def test_one_call_times_each_stage_within_its_own_time():
    scale = Scale(129, 1344, 32, seed=5)
    scale.one_call(0, scale.grid[0])  # compiled or loaded before timing
    start = time.perf_counter()
    seconds = scale.one_call(0, scale.grid[0])
    elapsed = time.perf_counter() - start
    assert len(seconds) == len(STAGES) == 3
    assert all(spent > 0 for spent in seconds), seconds
    assert sum(seconds) <= elapsed


def test_an_empty_band_changes_nothing():
    scale = Scale(97, 208, 16, seed=2)
    assert scale.one_call(2, 2) == (0.0, 0.0, 0.0)
    assert np.all(scale.scores == -0.5) and not scale.cells.any()


def test_only_the_default_cells_with_colour_maps_take_one_call():
    fits = Scale(72, 96, 16, seed=1)
    assert BandScorer.fits(fits.cell_rows, fits.colour_rows, fits.windows)
    # An odd number of cell columns takes the cell kernel's per-pixel tail.
    odd = Scale(72, 104, 16, seed=1)
    assert not BandScorer.fits(odd.cell_rows, odd.colour_rows, odd.windows)
    assert not BandScorer.fits(fits.cell_rows, None, fits.windows)
    grey = PhaseCellRows((72, 96, 1), (PPC, PPC), 9,
                         np.zeros(phase_layout_shape(9, 12, 1, 9, 2, 3), np.float32), 2, 3)
    assert not BandScorer.fits(grey, fits.colour_rows, fits.windows)
    with pytest.raises(ValueError, match="calls of their own"):
        BandScorer(odd.cell_rows, odd.colour_rows, odd.windows)


def test_without_a_kernel_clock_the_scales_keep_their_three_calls(monkeypatch):
    monkeypatch.setattr(band_module, "MONOTONIC_CLOCK", None)
    scale = Scale(72, 96, 16, seed=1)
    assert not BandScorer.fits(scale.cell_rows, scale.colour_rows, scale.windows)


def test_a_bound_band_scores_its_arrays_as_they_are_at_each_call():
    """``BandScorer.bind`` is made once and called on every frame, its arrays
    refilled in place: each call must compute what a fresh call computes."""
    height, width, step_px = SCALES[0]
    rows = window_count(height, WINDOW, step_px)
    bound_scale, fresh = (Scale(height, width, step_px, seed=1) for _ in range(2))
    top, bottom = bound_scale.rows(0, rows)
    band = BandScorer(bound_scale.cell_rows, bound_scale.colour_rows, bound_scale.windows)
    bound = band.bind(bound_scale.image, bound_scale.image[:bound_scale.covered], top, bottom,
                      0, rows, bound_scale.scores)
    rng = np.random.default_rng(4)
    for _ in range(3):
        pixels = rng.integers(0, 256, bound_scale.image.shape, dtype=np.uint8)
        for scale in (bound_scale, fresh):
            scale.image[...] = pixels
            scale.scores[...] = np.float32(-0.5)
        seconds = bound()
        fresh.one_call(0, rows)
        assert len(seconds) == len(STAGES) and min(seconds) >= 0
        for name in ("cells", "tiles", "box", "scores"):
            np.testing.assert_array_equal(getattr(bound_scale, name), getattr(fresh, name),
                                          err_msg=name)
    assert band.bind(bound_scale.image, bound_scale.image[:bound_scale.covered], top, bottom,
                     2, 2, bound_scale.scores)() == (0.0, 0.0, 0.0)
