"""The Numba kernels one at a time, on whole frames of four sizes.

Each kernel gets the input it gets in detection, built from the first frame
of the shared test video resized to the parameter size: the HLS image for
the gradient histograms, its cells for block normalisation and window
scoring, window-sized boxes for the heat map, the thresholded heat for
labelling.  Kernels are compiled (or loaded from Numba's cache) in ``setup``,
so only the run is timed.
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

from fastdet.kernels.blocks import normalize_blocks
from fastdet.kernels import colour, hog, score
from fastdet.kernels.heat import accumulate_heat
from fastdet.kernels.hog import cell_histograms
from fastdet.kernels.label import component_boxes, label_components
from fastdet.kernels.score import (
    add_hog_scores,
    add_hog_scores_from_phase_cells,
    phase_scoring_pad,
    window_count,
)

from ._common import SIZES, test_frame

PIXELS_PER_CELL = (8, 8)
CELLS_PER_BLOCK = (2, 2)
ORIENTATIONS = 9
NORM = "L2-Hys"
#: Blocks per 64-pixel window side (8 cells, 2-cell blocks).
BLOCKS_PER_WINDOW = 7
#: Window step in cells (50% overlap, the default scales' common step).
STEP_CELLS = 4
#: Hit boxes per frame for the heat and labelling kernels.
HITS = 300


def hls_image(label):
    return np.ascontiguousarray(cv2.cvtColor(test_frame(SIZES[label]), cv2.COLOR_BGR2HLS))


class GradientHistograms:
    """``cell_histograms``: gradients, orientation votes and cell pooling (3 channels)."""

    params = (list(SIZES), [False, True])
    param_names = ("frame_size", "parallel")

    def setup(self, label, parallel):
        self.image = hls_image(label)
        self.out = cell_histograms(self.image, PIXELS_PER_CELL, ORIENTATIONS, parallel=parallel)

    def time_cell_histograms(self, label, parallel):
        cell_histograms(self.image, PIXELS_PER_CELL, ORIENTATIONS, parallel=parallel,
                        out=self.out)


@functools.lru_cache(maxsize=None)
def _group_blocks_over_image(two_pass, fused_add):
    """A jitted walk of the cell kernel's interior group block (this CPU's lanes),
    in one or two passes, its masked adds fused or not, over every interior
    group of an image.  Not cached on disk: a variant the CPU does not use by
    default only exists here."""
    from numba import njit

    block = hog._group_block(3, 8, 8, ORIENTATIONS, False, False, two_pass=two_pass,
                             fused_add=fused_add)
    group = hog._GROUP_CELLS * 8 * 3

    @njit(nogil=True)
    def walk(flat, height, row_bytes, scratch):
        for y0 in range(0, height - 7, 8):
            for x0 in range(group, row_bytes - 2 * group + 1, group):
                block(flat, height, row_bytes, y0, x0, scratch)

    return walk


class CellBlockOrders:
    """The cell kernel's group block in one pass and in two (gradients first),
    with its masked adds as AND-then-add (or AVX-512's masked add) and as
    fused multiply-adds of 0.0 / 1.0.

    The kernel takes two passes on every CPU, and fuses the adds where it has
    FMA but not AVX-512; this times every combination on the machine at hand,
    so that the choices can be checked on every CPU (all give the same sums,
    bit for bit)."""

    params = (["1280x720"], [False, True], [False, True])
    param_names = ("frame_size", "two_pass", "fused_add")

    def setup(self, label, two_pass, fused_add):
        image = hls_image(label)
        self.args = (image.ravel(), image.shape[0], image.shape[1] * 3,
                     np.empty(hog._reduction_plan(hog._LANES, 3, 8, ORIENTATIONS).size,
                              np.float32))
        self.walk = _group_blocks_over_image(two_pass, fused_add)
        self.walk(*self.args)

    def time_group_blocks(self, label, two_pass, fused_add):
        self.walk(*self.args)


@functools.lru_cache(maxsize=None)
def spatial_grid_walk(fixed, windows=score._DOT_WINDOWS):
    """A jitted walk of the spatial dot block over a grid of windows,
    ``windows`` a call: the block for the default 96-element rows (``fixed``)
    or the general one.  Not cached on disk, like
    :func:`_group_blocks_over_image`; the tests compare the two with it."""
    from numba import njit

    dots = score._row_window_dots(windows, score.SPATIAL_ROW if fixed else None)

    @njit(nogil=True)
    def walk(image2d, weights2d, step_rows, step_cols, out):
        rows, length = weights2d.shape
        image_flat, weights_flat = image2d.ravel(), weights2d.ravel()
        for iy in range(out.shape[0]):
            cols = out.shape[1]
            for ix in range(0, cols, windows):
                dots(image_flat, image2d.shape[1], iy * step_rows, ix * step_cols, step_cols,
                     weights_flat, rows, length, out[iy], ix, min(windows, cols - ix))

    return walk


@functools.lru_cache(maxsize=None)
def _hog_rows_walk(rows):
    """A jitted walk of the HOG window-dot block scoring 12 window rows of 128
    positions, ``rows`` window rows a call (three channels of 36 features)."""
    from numba import njit

    dots = score._window_dots(rows)

    @njit(nogil=True)
    def walk(weights, blocks, stride, second, channels, per_channel, acc, n_rows):
        features = channels * per_channel
        for group in range(0, n_rows, rows):
            for chunk in range(0, stride, 16):
                dots(weights, group * features, features, blocks, stride, chunk, second,
                     channels, per_channel, acc, group * stride + chunk, stride)

    return walk


class WindowDotBlocks:
    """The window-score blocks in the forms a CPU may take (all give the same bits).

    ``spatial``: the default spatial rows (96 elements) dotted by the general
    block or by the one with each row written out (the detector takes the
    latter); ``hog rows N``: a block row's HOG features dotted with N window
    rows at once (the detector takes four with AVX-512, three with AVX2, one
    without).  Timing both forms on the machine at hand checks the choices."""

    params = (["spatial general", "spatial rows written out", "hog rows 1", "hog rows 2",
               "hog rows 3", "hog rows 4"],)
    param_names = ("block",)

    def setup(self, block):
        rng = np.random.default_rng(0)
        if block.startswith("spatial"):
            image = rng.normal(size=(66, 640 * 3)).astype(np.float32)
            weights = rng.normal(size=(32, score.SPATIAL_ROW)).astype(np.float32)
            self.args = (image, weights, 8, 24, np.zeros((4, 77), np.float32))
            self.walk = spatial_grid_walk(block.endswith("written out"))
        else:
            channels, per_channel, stride, n_rows = 3, 36, 128, 12
            self.args = (rng.normal(size=n_rows * channels * per_channel).astype(np.float32),
                         rng.normal(size=channels * per_channel * stride + 16).astype(np.float32),
                         stride, rng.random(channels * stride + 16).astype(np.float32),
                         channels, per_channel, np.zeros(n_rows * stride + 16, np.float32),
                         n_rows)
            self.walk = _hog_rows_walk(int(block.split()[-1]))
        self.walk(*self.args)

    def time_window_dots(self, block):
        self.walk(*self.args)


class ColourTileSums:
    """The colour histogram's tile sums over a whole HLS frame (tiles of 16).

    ``vector`` is the bin-table path this CPU's kernels have (AVX-512BW or
    AVX2; the detector's lut has 32 bins), ``scalar`` the per-pixel lookups
    that serve any lut (and CPUs with neither)."""

    params = (["1280x720"], ["vector", "scalar"])
    param_names = ("frame_size", "path")

    def setup(self, label, path):
        self.image = hls_image(label)
        weights = np.random.default_rng(0).normal(size=(3, 32)).astype(np.float32)
        self.lut = np.ascontiguousarray(weights[:, np.arange(256) // 8])
        height, width = self.image.shape[:2]
        self.tiles = np.empty((height // 16, width // 16), np.float32)
        self.box = np.empty((0, 0, 3), np.float32)
        self.table = colour.bin_table(self.lut)
        self.path = colour.TILE_PATH if path == "vector" else colour.PATH_SCALAR
        self.time_tile_sums(label, path)

    def time_tile_sums(self, label, path):
        colour._colour_maps(self.path, self.image, self.lut, self.table, 16, 0, True, False,
                            self.tiles, self.box)


class BlockNormalisation:
    """``normalize_blocks``: L2-Hys over every 2x2-cell block of the cell map."""

    params = (list(SIZES), [False, True])
    param_names = ("frame_size", "parallel")

    def setup(self, label, parallel):
        self.cells = cell_histograms(hls_image(label), PIXELS_PER_CELL, ORIENTATIONS)
        self.out = normalize_blocks(self.cells, CELLS_PER_BLOCK, NORM, parallel=parallel)

    def time_normalize_blocks(self, label, parallel):
        normalize_blocks(self.cells, CELLS_PER_BLOCK, NORM, parallel=parallel, out=self.out)


class WindowScoring:
    """HOG part of every 64x64 window's SVM score, step 4 cells.

    ``fused`` is the detector's path (cells in the phase layout of the step,
    each block row normalised and scored at once, never writing the block
    map); ``from_blocks`` scores a ready block map (``add_hog_scores``, for
    comparison).
    """

    params = (list(SIZES),)
    param_names = ("frame_size",)

    def setup(self, label):
        image = hls_image(label)
        self.cells = cell_histograms(image, PIXELS_PER_CELL, ORIENTATIONS)
        pad = phase_scoring_pad(self.cells.shape[1], STEP_CELLS, CELLS_PER_BLOCK)
        self.phase_cells = cell_histograms(image, PIXELS_PER_CELL, ORIENTATIONS,
                                           phase_step=STEP_CELLS, phase_pad=pad)
        self.blocks = normalize_blocks(self.cells, CELLS_PER_BLOCK, NORM)
        rng = np.random.default_rng(0)
        self.weights = rng.standard_normal(
            (BLOCKS_PER_WINDOW, BLOCKS_PER_WINDOW, self.blocks.shape[2])).astype(np.float32)
        grid = (window_count(self.blocks.shape[0], BLOCKS_PER_WINDOW, STEP_CELLS),
                window_count(self.blocks.shape[1], BLOCKS_PER_WINDOW, STEP_CELLS))
        self.scores = np.zeros(grid, np.float32)
        self.time_fused(label)
        self.time_from_blocks(label)

    def time_fused(self, label):
        add_hog_scores_from_phase_cells(self.phase_cells, self.cells.shape[1], CELLS_PER_BLOCK,
                                        NORM, self.weights, STEP_CELLS, self.scores)

    def time_from_blocks(self, label):
        add_hog_scores(self.blocks, self.weights, STEP_CELLS, self.scores)

    def track_windows(self, label):
        return int(self.scores.size)

    track_windows.unit = "windows"


def hit_boxes(size, count=HITS, seed=0):
    """``count`` window-like boxes (48 to 160 px at 1280x720, scaled) in the lower half."""
    width, height = size
    k = width / 1280
    rng = np.random.default_rng(seed)
    sides = (rng.uniform(48, 160, count) * k).astype(np.int32)
    x1 = (rng.uniform(0, 1, count) * (width - sides)).astype(np.int32)
    y1 = (height // 2 + rng.uniform(0, 1, count) * (height // 2 - sides)).astype(np.int32)
    return np.stack([x1, y1, x1 + sides, y1 + sides], axis=1).astype(np.int32)


class HeatAccumulation:
    """``accumulate_heat``: 300 hit boxes into a frame-sized heat map."""

    params = (list(SIZES),)
    param_names = ("frame_size",)

    def setup(self, label):
        self.size = SIZES[label]
        self.boxes = hit_boxes(self.size)
        self.weights = np.ones(len(self.boxes), np.float32)
        self.time_accumulate_heat(label)

    def time_accumulate_heat(self, label):
        accumulate_heat(self.boxes, self.weights, self.size[1], self.size[0])


class Labelling:
    """``label_components`` + ``component_boxes`` on the thresholded heat (8-connected)."""

    params = (list(SIZES),)
    param_names = ("frame_size",)

    def setup(self, label):
        width, height = SIZES[label]
        boxes = hit_boxes((width, height))
        heat = accumulate_heat(boxes, np.ones(len(boxes), np.float32), height, width)
        self.mask = heat > 1
        self.time_label_and_box(label)

    def time_label_and_box(self, label):
        labels, count = label_components(self.mask, 8)
        component_boxes(labels, count)
