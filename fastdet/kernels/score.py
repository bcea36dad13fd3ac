"""Linear-SVM scores of every sliding window of one scale, without per-window extraction.

A window's decision value is ``bias + w_hog . hog + w_spatial . spatial +
w_hist . hist``.  Each part is added into an ``(Ny, Nx)`` score grid by its
own kernel, reading maps computed once per scale:

* HOG: from a ready block map, the window's ``n x n`` blocks are ``n``
  contiguous runs (one per block row) dotted with the matching rows of the
  weights (:func:`add_hog_scores`); from cells in the phase layout of the
  window step, each block row is normalised once along the whole row and
  added into the windows that contain it
  (:func:`add_hog_scores_from_phase_cells`, what the detector uses);
* spatial: likewise, ``S`` contiguous pixel rows of the box-averaged image;
* histogram: the part is linear in the per-pixel bin indicators, so it equals
  the window sum of a per-pixel weight ``sum_c lut[c, value_c]``; windows are
  made of whole tiles, so an integral image over per-tile sums gives it in
  four reads per window.

Window ``(iy, ix)`` has its top-left pixel at ``(iy * step_px, ix * step_px)``
of the scale's image (``step_px`` = cells per step x pixels per cell).
"""

import numba
import numpy as np
from numba import njit, prange, uint64

from .blocks import EPS, NORM_CODES
from .hog import to_phase_layout

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


@njit(cache=True, nogil=True)
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


def add_hog_scores_from_cells(cells, cells_per_block, norm, weights, step_cells, out, eps=EPS):
    """Normalise blocks and add every window's HOG score in one pass.

    Equivalent to :func:`fastdet.kernels.blocks.normalize_blocks` followed by
    :func:`add_hog_scores`, without writing the block map: the cells are
    copied into the phase layout and scored by
    :func:`add_hog_scores_from_phase_cells` (the detector computes that
    layout directly).

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
    phase = to_phase_layout(cells, step_cells, int(cells_per_block[1]))
    add_hog_scores_from_phase_cells(phase, cells.shape[1], cells_per_block, norm, weights,
                                    step_cells, out, eps)


@njit(cache=True, fastmath=_FASTMATH)
def _phase_energy(cells_flat, base, nbins, length, norm_code, energy, e_base):
    """energy[e_base + i] = sum over bins of |v| (L1 norms) or v**2 (L2 norms)."""
    for i in range(uint64(length)):
        energy[e_base + i] = 0.0
    for b in range(uint64(nbins)):
        row = base + b * uint64(length)
        if norm_code <= 1:
            for i in range(uint64(length)):
                energy[e_base + i] += abs(cells_flat[row + i])
        else:
            for i in range(uint64(length)):
                v = cells_flat[row + i]
                energy[e_base + i] += v * v


@njit(cache=True, fastmath=_FASTMATH)
def _add_run(src, s0, dst, d0, count):
    for i in range(uint64(count)):
        dst[d0 + i] += src[s0 + i]


@njit(cache=True, fastmath=_FASTMATH)
def _inverse_norm(total, count, norm_code, eps, inv):
    eps32 = np.float32(eps)
    eps_sq = np.float32(eps * eps)
    for i in range(uint64(count)):
        if norm_code <= 1:
            inv[i] = np.float32(1.0) / (total[i] + eps32)
        else:
            inv[i] = np.float32(1.0) / np.sqrt(total[i] + eps_sq)


@njit(cache=True, fastmath=_FASTMATH)
def _scale_run(src, s0, inv, i0, count, dst, d0):
    """dst = src * inv (L1 and L2)."""
    for i in range(uint64(count)):
        dst[d0 + i] = src[s0 + i] * inv[i0 + i]


@njit(cache=True, fastmath=_FASTMATH)
def _scale_sqrt_run(src, s0, inv, i0, count, dst, d0):
    """dst = sqrt(src * inv) (L1-sqrt)."""
    for i in range(uint64(count)):
        dst[d0 + i] = np.sqrt(src[s0 + i] * inv[i0 + i])


@njit(cache=True, fastmath=_FASTMATH)
def _scale_clip_run(src, s0, inv, i0, count, dst, d0, sum_sq):
    """dst = min(src * inv, 0.2), and its squares added to sum_sq (L2-Hys)."""
    clip = np.float32(0.2)
    for i in range(uint64(count)):
        v = min(src[s0 + i] * inv[i0 + i], clip)
        dst[d0 + i] = v
    # A separate pass: one store stream per loop vectorises best.
    for i in range(uint64(count)):
        v = dst[d0 + i]
        sum_sq[i0 + i] += v * v


@njit(cache=True, fastmath=_FASTMATH)
def _add_scaled_run(src, scale, s0, dst, d0, count):
    """dst += src * scale[s0:] (src and dst from 0 and d0)."""
    for i in range(uint64(count)):
        dst[d0 + i] += src[i] * scale[s0 + i]


@njit(cache=True, fastmath=_FASTMATH)
def _axpy(weight, src, s0, count, dst, d0):
    for i in range(uint64(count)):
        dst[d0 + i] += weight * src[s0 + i]


@njit(cache=True, fastmath=_FASTMATH)
def _axpy4(weights, w0, src, s0, stride, count, dst):
    """dst += sum over q < 4 of weights[w0 + q] * src[s0 + q * stride:][:count]."""
    a = weights[w0]
    b = weights[w0 + uint64(1)]
    c = weights[w0 + uint64(2)]
    d = weights[w0 + uint64(3)]
    s1 = s0 + stride
    s2 = s1 + stride
    s3 = s2 + stride
    for i in range(uint64(count)):
        dst[i] += a * src[s0 + i] + b * src[s1 + i] + c * src[s2 + i] + d * src[s3 + i]


@njit(cache=True)
def _shift_runs(dx, step, per_phase):
    """Runs ``(dest, src, count)`` mapping block positions to their cell ``bx + dx``.

    Phases whose cell ``bx + dx`` wraps into the same later phase index form
    one contiguous run in both layouts, so there are at most a few runs.
    """
    runs = np.empty((step, 3), dtype=np.uint64)
    n = 0
    p = 0
    while p < step:
        wrap = (p + dx) // step
        p_end = min(step, (wrap + 1) * step - dx)
        q = p + dx - wrap * step
        runs[n, 0] = p * per_phase
        runs[n, 1] = q * per_phase + wrap
        runs[n, 2] = (p_end - p) * per_phase
        n += 1
        p = p_end
    return runs[:n]


@njit(cache=True, nogil=True)
def _add_hog_scores_phase(cells, per_phase, cpb_y, cpb_x, norm_code, eps, weights, step, out,
                          first_row, stop_row):
    """Scores of window rows ``first_row`` .. ``stop_row - 1`` (a band)."""
    rows, channels, nbins, length = cells.shape
    n = weights.shape[0]
    n_features = weights.shape[2]
    positions = uint64(step * per_phase)
    cells_flat = cells.reshape(cells.size)
    weights_flat = weights.reshape(weights.size)
    out_flat = out.reshape(out.size)
    rows_out, cols_out = out.shape
    if first_row >= stop_row:
        return
    first_block = first_row * step
    stop_block = (stop_row - 1) * step + n
    # Per cell of the band's block rows: the sum a block norm is built from.
    energy = np.empty(rows * channels * length, dtype=np.float32)
    for cy in range(first_block, stop_block + cpb_y - 1):
        for c in range(channels):
            base = uint64((cy * channels + c) * nbins * length)
            _phase_energy(cells_flat, base, nbins, length, norm_code, energy,
                          uint64((cy * channels + c) * length))
    runs = [_shift_runs(dx, step, per_phase) for dx in range(cpb_x)]
    per_channel = cpb_y * cpb_x * nbins
    normalised = np.empty(n_features * positions, dtype=np.float32)
    total = np.empty(positions, dtype=np.float32)
    inv = np.empty(positions, dtype=np.float32)
    sum_sq = np.empty(positions, dtype=np.float32)
    partial = np.empty(cols_out, dtype=np.float32)
    second = np.empty(channels * positions, dtype=np.float32)
    for by in range(first_block, stop_block):
        for c in range(channels):
            total[:] = 0.0
            for dy in range(cpb_y):
                e_base = uint64(((by + dy) * channels + c) * length)
                for dx in range(cpb_x):
                    for k in range(runs[dx].shape[0]):
                        _add_run(energy, e_base + runs[dx][k, 1], total, runs[dx][k, 0],
                                 runs[dx][k, 2])
            _inverse_norm(total, positions, norm_code, eps, inv)
            sum_sq[:] = 0.0
            f = uint64(c * per_channel)
            for dy in range(cpb_y):
                c_base = uint64(((by + dy) * channels + c) * nbins * length)
                for dx in range(cpb_x):
                    for b in range(nbins):
                        row = c_base + uint64(b * length)
                        for k in range(runs[dx].shape[0]):
                            src = row + runs[dx][k, 1]
                            start = runs[dx][k, 0]
                            count = runs[dx][k, 2]
                            dest = f * positions + start
                            if norm_code == 3:
                                _scale_clip_run(cells_flat, src, inv, start, count, normalised,
                                                dest, sum_sq)
                            elif norm_code == 1:
                                _scale_sqrt_run(cells_flat, src, inv, start, count, normalised,
                                                dest)
                            else:
                                _scale_run(cells_flat, src, inv, start, count, normalised, dest)
                        f += uint64(1)
            if norm_code == 3:
                # L2-Hys's second normalisation is applied to the blocks' dot
                # products instead of to every clipped value.
                _inverse_norm(sum_sq, positions, 2, eps, second[c * positions:])
        # Window rows iy whose n block rows include ``by``.
        first = max(first_row, (by - n + step) // step)
        last = min(stop_row - 1, by // step)
        for iy in range(first, last + 1):
            r = by - iy * step
            for s in range(n):
                offset = uint64((s % step) * per_phase + s // step)
                w_base = uint64((r * n + s) * n_features)
                # One block channel's dot products first, then into the
                # scores: short sums keep float32 rounding near a plain dot's.
                for c in range(channels):
                    partial[:] = 0.0
                    f = uint64(c * per_channel)
                    stop = uint64((c + 1) * per_channel)
                    # Four features per pass: a quarter of the passes over partial.
                    while f + uint64(4) <= stop:
                        _axpy4(weights_flat, w_base + f, normalised, f * positions + offset,
                               positions, cols_out, partial)
                        f += uint64(4)
                    while f < stop:
                        _axpy(weights_flat[w_base + f], normalised, f * positions + offset,
                              cols_out, partial, uint64(0))
                        f += uint64(1)
                    if norm_code == 3:
                        _add_scaled_run(partial, second, uint64(c) * positions + offset,
                                        out_flat, uint64(iy * cols_out), cols_out)
                    else:
                        _add_run(partial, uint64(0), out_flat, uint64(iy * cols_out), cols_out)


@njit(cache=True, parallel=True)
def _add_hog_scores_phase_parallel(cells, per_phase, cpb_y, cpb_x, norm_code, eps, weights, step,
                                   out, bands):
    # Bands of window rows write disjoint score rows; block rows on a band
    # edge are normalised by both bands.
    rows_out = out.shape[0]
    for band in prange(bands):
        _add_hog_scores_phase(cells, per_phase, cpb_y, cpb_x, norm_code, eps, weights, step, out,
                              band * rows_out // bands, (band + 1) * rows_out // bands)


def add_hog_scores_from_phase_cells(cells, cells_x, cells_per_block, norm, weights, step_cells,
                                    out, eps=EPS, parallel=False):
    """Normalise blocks and add every window's HOG score, one block row at a time.

    Equivalent to :func:`fastdet.kernels.blocks.normalize_blocks` followed by
    :func:`add_hog_scores`, but the block map is never written to memory and
    every loop runs along a whole row of blocks (vectorised).  The cells come
    in the phase layout of :func:`fastdet.kernels.hog.phase_layout_shape` for
    ``step_cells``: the blocks a row of windows reads at any offset are then
    contiguous.

    Parameters
    ----------
    cells : ndarray of float32, shape (Hc, C, nbins, L)
        Phase-layout cells, with at least ``cells_per_block[1]`` padding.
    cells_x : int
        Cell columns ``Wc`` of the grid.
    cells_per_block : tuple of int
    norm : str
        Block norm, as in :func:`~fastdet.kernels.blocks.normalize_blocks`.
    weights : ndarray of float32, shape (n, n, F)
        HOG weights of one window, blocks ordered (channel, cell_y, cell_x, bin).
    step_cells : int
    out : ndarray of float32, shape (Ny, Nx)
        Score grid, added to in place.
    eps : float
    parallel : bool
        Spread bands of window rows over Numba's threads.
    """
    cpb_y, cpb_x = int(cells_per_block[0]), int(cells_per_block[1])
    n, _, length = weights.shape
    rows, channels, nbins, positions = cells.shape
    if length != channels * cpb_y * cpb_x * nbins:
        raise ValueError(f"weights have {length} features per block, cells give "
                         f"{channels * cpb_y * cpb_x * nbins}")
    per_phase = -(-int(cells_x) // step_cells)
    if positions < step_cells * per_phase + cpb_x:
        raise ValueError(f"phase-layout cells need {step_cells * per_phase + cpb_x} positions "
                         f"for {cells_x} columns stepped by {step_cells}, got {positions}")
    blocks_shape = (rows - cpb_y + 1, cells_x - cpb_x + 1)
    _check_fits(out, blocks_shape, (n, n), step_cells)
    if out.size == 0:
        return
    args = (cells, per_phase, cpb_y, cpb_x, NORM_CODES[norm], float(eps), weights,
            int(step_cells), out)
    bands = min(numba.get_num_threads(), out.shape[0]) if parallel else 1
    if bands > 1:
        _add_hog_scores_phase_parallel(*args, bands)
    else:
        _add_hog_scores_phase(*args, 0, out.shape[0])


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


@njit(cache=True, nogil=True)
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
    per-tile weight sums of :func:`fastdet.kernels.colour.colour_maps`.

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
