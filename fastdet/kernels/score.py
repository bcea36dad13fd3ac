"""Linear-SVM scores of every sliding window of one scale, without per-window extraction.

A window's decision value is ``bias + w_hog . hog + w_spatial . spatial +
w_hist . hist``.  Each part is added into an ``(Ny, Nx)`` score grid by its
own kernel, reading maps computed once per scale:

* HOG: the window's ``n x n`` blocks are ``n`` contiguous runs of the block
  map (one per block row), dotted with the matching rows of the weights;
* spatial: likewise, ``S`` contiguous pixel rows of the box-averaged image;
* histogram: the part is linear in the per-pixel bin indicators, so it equals
  the window sum of a per-pixel weight ``sum_c lut[c, value_c]``; windows are
  made of whole tiles, so an integral image over per-tile sums gives it in
  four reads per window.

Window ``(iy, ix)`` has its top-left pixel at ``(iy * step_px, ix * step_px)``
of the scale's image (``step_px`` = cells per step x pixels per cell).
"""

import numpy as np
from numba import njit, prange, uint64

from .blocks import EPS, NORM_CODES, _normalize_block_row, cell_energy

# Reassociation lets LLVM vectorise the dot products; sums then differ from
# strict left-to-right order only at float32 rounding level.
_FASTMATH = {"reassoc", "nsz", "contract"}


@njit(cache=True, fastmath=_FASTMATH)
def _dot_rows(image_flat, row_len, y0, x0, weights_flat, rows, length):
    """Sum over r, k of image[y0 + r, x0 + k] * weights[r, k] on flat arrays.

    Unsigned indices: Numba's negative-index wraparound would otherwise keep
    LLVM from vectorising the inner product.
    """
    total = np.float32(0.0)
    for r in range(uint64(rows)):
        base = (uint64(y0) + r) * uint64(row_len) + uint64(x0)
        w_base = r * uint64(length)
        partial = np.float32(0.0)
        for k in range(uint64(length)):
            partial += image_flat[base + k] * weights_flat[w_base + k]
        total += partial
    return total


@njit(cache=True)
def _add_grid(image2d, weights2d, step_rows, step_cols, out):
    rows, length = weights2d.shape
    image_flat = image2d.reshape(image2d.size)
    weights_flat = weights2d.reshape(weights2d.size)
    for iy in range(out.shape[0]):
        for ix in range(out.shape[1]):
            out[iy, ix] += _dot_rows(image_flat, image2d.shape[1], iy * step_rows, ix * step_cols,
                                     weights_flat, rows, length)


@njit(cache=True, parallel=True)
def _add_grid_parallel(image2d, weights2d, step_rows, step_cols, out):
    rows, length = weights2d.shape
    image_flat = image2d.reshape(image2d.size)
    weights_flat = weights2d.reshape(weights2d.size)
    for iy in prange(out.shape[0]):
        for ix in range(out.shape[1]):
            out[iy, ix] += _dot_rows(image_flat, image2d.shape[1], iy * step_rows, ix * step_cols,
                                     weights_flat, rows, length)


def add_hog_scores(blocks, weights, step_cells, out, parallel=False):
    """Add the HOG part of every window's score to ``out``.

    Parameters
    ----------
    blocks : ndarray of float32, shape (Hb, Wb, F)
        Block map of the scale (C-contiguous).
    weights : ndarray of float32, shape (n, n, F)
        HOG weights of one window, in block-map order.
    step_cells : int
        Window step in cells (= blocks).
    out : ndarray of float32, shape (Ny, Nx)
        Score grid, added to in place; every window must fit in ``blocks``.
    parallel : bool
        Spread window rows over Numba's threads.
    """
    n, _, length = weights.shape
    _check_fits(out, blocks.shape[:2], (n, n), step_cells)
    image2d = blocks.reshape(blocks.shape[0], blocks.shape[1] * length)
    weights2d = weights.reshape(n, n * length)
    kernel = _add_grid_parallel if parallel else _add_grid
    kernel(image2d, weights2d, step_cells, step_cells * length, out)


@njit(cache=True)
def _add_hog_scores_fused(cells, energy, cpb_y, cpb_x, norm_code, eps, weights2d, step, out):
    n = weights2d.shape[0]
    block_len = cells.shape[2] * cpb_y * cpb_x * cells.shape[3]
    row = np.empty((cells.shape[1] - cpb_x + 1) * block_len, dtype=np.float32)
    rows_out, cols_out = out.shape
    weights_flat = weights2d.reshape(weights2d.size)
    for by in range((rows_out - 1) * step + n):
        _normalize_block_row(cells, energy, by, cpb_y, cpb_x, norm_code, eps, row)
        # Window rows iy whose n block rows include ``by``.
        first = max(0, (by - n + step) // step)
        last = min(rows_out - 1, by // step)
        for iy in range(first, last + 1):
            r = by - iy * step
            for ix in range(cols_out):
                out[iy, ix] += _dot_rows(row, row.size, 0, ix * step * block_len,
                                         weights_flat[r * n * block_len:], 1, n * block_len)


def add_hog_scores_from_cells(cells, cells_per_block, norm, weights, step_cells, out, eps=EPS):
    """Normalise blocks and add every window's HOG score in one pass.

    Equivalent to :func:`fastdet.kernels.blocks.normalize_blocks` followed by
    :func:`add_hog_scores`, but each block row is normalised into a small
    scratch row and immediately dotted with the windows that contain it, so
    the block map (several megabytes per frame) is never written to memory.

    Parameters
    ----------
    cells : ndarray of float32, shape (Hc, Wc, C, nbins)
    cells_per_block : tuple of int
    norm : str
        Block norm, as in :func:`~fastdet.kernels.blocks.normalize_blocks`.
    weights : ndarray of float32, shape (n, n, F)
    step_cells : int
    out : ndarray of float32, shape (Ny, Nx)
    eps : float
    """
    cpb_y, cpb_x = int(cells_per_block[0]), int(cells_per_block[1])
    n, _, length = weights.shape
    if length != cells.shape[2] * cpb_y * cpb_x * cells.shape[3]:
        raise ValueError(f"weights have {length} features per block, cells give "
                         f"{cells.shape[2] * cpb_y * cpb_x * cells.shape[3]}")
    blocks_shape = (cells.shape[0] - cpb_y + 1, cells.shape[1] - cpb_x + 1)
    _check_fits(out, blocks_shape, (n, n), step_cells)
    if out.size == 0:
        return
    norm_code = NORM_CODES[norm]
    _add_hog_scores_fused(cells, cell_energy(cells, norm_code), cpb_y, cpb_x, norm_code,
                          float(eps), weights.reshape(n, n * length), step_cells, out)


def add_spatial_scores(spatial, weights, step_px, out, parallel=False):
    """Add the spatial-colour part of every window's score to ``out``.

    Parameters
    ----------
    spatial : ndarray of float32, shape (Hs, Ws, 3)
        Box-averaged colour image of the scale (C-contiguous).
    weights : ndarray of float32, shape (S, S, 3)
    step_px : int
        Window step in pixels of ``spatial``.
    out : ndarray of float32, shape (Ny, Nx)
    parallel : bool
    """
    size, _, channels = weights.shape
    _check_fits(out, spatial.shape[:2], (size, size), step_px)
    image2d = spatial.reshape(spatial.shape[0], spatial.shape[1] * channels)
    weights2d = weights.reshape(size, size * channels)
    kernel = _add_grid_parallel if parallel else _add_grid
    kernel(image2d, weights2d, step_px, step_px * channels, out)


@njit(cache=True)
def _add_tile_window_sums(tiles, size, step, out):
    """out[iy, ix] += sum of tiles[iy*step : +size, ix*step : +size]."""
    rows, cols = tiles.shape
    integral = np.zeros((rows + 1, cols + 1), dtype=np.float64)
    for y in range(rows):
        running = 0.0
        for x in range(cols):
            running += tiles[y, x]
            integral[y + 1, x + 1] = integral[y, x + 1] + running
    for iy in range(out.shape[0]):
        y0 = iy * step
        for ix in range(out.shape[1]):
            x0 = ix * step
            out[iy, ix] += (integral[y0 + size, x0 + size] - integral[y0, x0 + size]
                            - integral[y0 + size, x0] + integral[y0, x0])


def add_tile_window_sums(tiles, tiles_per_window, step_tiles, out):
    """Add each window's sum of per-tile values to ``out``.

    Used for the colour-histogram part of the score: ``tiles`` are the
    per-tile weight sums of :func:`fastdet.kernels.colour.tile_weight_sums`.

    Parameters
    ----------
    tiles : ndarray of float32, shape (Ty, Tx)
    tiles_per_window : int
        Window side in tiles.
    step_tiles : int
        Window step in tiles.
    out : ndarray of float32, shape (Ny, Nx)
    """
    _check_fits(out, tiles.shape, (tiles_per_window, tiles_per_window), step_tiles)
    _add_tile_window_sums(tiles, tiles_per_window, step_tiles, out)


def _check_fits(out, map_shape, window_shape, step):
    for axis in range(2):
        if out.shape[axis] and (out.shape[axis] - 1) * step + window_shape[axis] > map_shape[axis]:
            raise ValueError(f"{out.shape[axis]} windows of {window_shape[axis]} stepped by {step} "
                             f"do not fit in a map of {map_shape[axis]} along axis {axis}")


def window_count(map_length, window_length, step):
    """Number of windows of ``window_length`` stepped by ``step`` along an axis."""
    if map_length < window_length:
        return 0
    return (map_length - window_length) // step + 1
