"""Block normalisation of cell histograms (the block stage of HOG).

Blocks of ``cpb_y x cpb_x`` cells, stepped one cell at a time, are normalised
per channel with one of scikit-image's four schemes.  The output keeps every
block's features contiguous, ordered ``(channel, cell_y, cell_x, bin)``, so a
detection window is ``blocks[by:by + n, bx:bx + n]`` read row by row: the same
order the training features use (see ``fastdet.detector.features``).
"""

import numpy as np
from numba import njit, prange, uint64

from .hog import _output
from .views import flat as flat_view

#: Codes of the normalisation schemes, by scikit-image name.
NORM_CODES = {"L1": 0, "L1-sqrt": 1, "L2": 2, "L2-Hys": 3}

#: scikit-image's epsilon in ``_hog_normalize_block``.
EPS = 1e-5


# No reassociating or contracting fastmath: LLVM would then pick the partial
# sums of the reductions by the target's vector width (16 lanes on an AMD Zen 4
# with AVX-512, 8 with AVX2) and fuse products into sums only where the CPU has
# FMA, so each CPU would round the features its own way.  The element-wise
# loops vectorise without it; the one long reduction (L2-Hys's second sum of
# squares) keeps four running sums in a fixed order (_clip_sum_of_squares).
@njit(cache=True, nogil=True)
def _cell_energy(cells, norm_code, energy):
    """Per cell and channel: sum of |v| (L1 norms) or of v**2 (L2 norms)."""
    n_y, n_x, channels, nbins = cells.shape
    for cy in range(n_y):
        for cx in range(n_x):
            for c in range(channels):
                total = np.float32(0.0)
                for b in range(nbins):
                    v = cells[cy, cx, c, b]
                    total += abs(v) if norm_code <= 1 else v * v
                energy[cy, cx, c] = total


def cell_energy(cells, norm_code):
    """Per cell and channel, the sum a block norm is built from (float32 (Hc, Wc, C))."""
    energy = np.empty(cells.shape[:3], dtype=np.float32)
    _cell_energy(cells, norm_code, energy)
    return energy


@njit(cache=True, nogil=True, inline="always")
def _clip_sum_of_squares(row, start, stop, clip):
    """Clip ``row[start:stop]`` at ``clip`` in place; the sum of the clipped
    values' squares, element ``i`` of each whole four in running sum
    ``(i - start) % 4`` and the last ``(stop - start) % 4`` in the first, the
    four then added as ``(s0 + s1) + (s2 + s3)``: independent chains, a fixed
    order."""
    s0 = s1 = s2 = s3 = np.float32(0.0)
    i = start
    while i + uint64(4) <= stop:
        v0, v1 = min(row[i], clip), min(row[i + 1], clip)
        v2, v3 = min(row[i + 2], clip), min(row[i + 3], clip)
        row[i], row[i + 1], row[i + 2], row[i + 3] = v0, v1, v2, v3
        s0 += v0 * v0
        s1 += v1 * v1
        s2 += v2 * v2
        s3 += v3 * v3
        i += uint64(4)
    while i < stop:
        v = min(row[i], clip)
        row[i] = v
        s0 += v * v
        i += uint64(1)
    return (s0 + s1) + (s2 + s3)


@njit(cache=True, nogil=True)
def _normalize_block_row(cells, energy, by, cpb_y, cpb_x, norm_code, eps, dest_row):
    """Normalise every block whose top-left cell is in cell row ``by``.

    ``dest_row`` is the flat output row: ``n_blocks_x`` blocks of
    ``C * cpb_y * cpb_x * nbins`` features each.

    Works on flat rows with unsigned indices: Numba's negative-index
    wraparound would otherwise keep LLVM from vectorising the copies.
    """
    n_cells_x, channels, nbins = cells.shape[1], cells.shape[2], cells.shape[3]
    cell_len = uint64(channels * nbins)
    nb = uint64(nbins)
    per_channel = uint64(cpb_y * cpb_x * nbins)
    block_len = uint64(channels) * per_channel
    n_blocks_x = uint64(dest_row.size) // block_len
    eps32 = np.float32(eps)
    eps_sq = np.float32(eps * eps)
    clip = np.float32(0.2)
    src_all = flat_view(cells)
    row_len = uint64(n_cells_x) * cell_len
    for bx in range(n_blocks_x):
        for c in range(uint64(channels)):
            total = np.float32(0.0)
            for cy in range(cpb_y):
                for cx in range(uint64(cpb_x)):
                    total += energy[by + cy, bx + cx, c]
            if norm_code <= 1:
                inv = np.float32(1.0) / (total + eps32)
            else:
                inv = np.float32(1.0) / np.sqrt(total + eps_sq)
            base = bx * block_len + c * per_channel
            n = base
            for cy in range(uint64(cpb_y)):
                for cx in range(uint64(cpb_x)):
                    src = (uint64(by) + cy) * row_len + (bx + cx) * cell_len + c * nb
                    for b in range(nb):
                        dest_row[n + b] = src_all[src + b] * inv
                    n += nb
            if norm_code == 1:
                for i in range(base, base + per_channel):
                    dest_row[i] = np.sqrt(dest_row[i])
            elif norm_code == 3:
                total = _clip_sum_of_squares(dest_row, base, base + per_channel, clip)
                inv = np.float32(1.0) / np.sqrt(total + eps_sq)
                for i in range(base, base + per_channel):
                    dest_row[i] *= inv


@njit(cache=True, nogil=True)
def _normalize_serial(cells, energy, cpb_y, cpb_x, norm_code, eps, out):
    for by in range(out.shape[0]):
        _normalize_block_row(cells, energy, by, cpb_y, cpb_x, norm_code, eps,
                             out[by].reshape(out.shape[1] * out.shape[2]))


@njit(cache=True, parallel=True)
def _normalize_parallel(cells, energy, cpb_y, cpb_x, norm_code, eps, out):
    for by in prange(out.shape[0]):
        _normalize_block_row(cells, energy, by, cpb_y, cpb_x, norm_code, eps,
                             out[by].reshape(out.shape[1] * out.shape[2]))


@njit(cache=True, nogil=True)
def _normalize_block_f64(block, norm_code, eps):
    """One block of one channel, normalised in place as scikit-image's
    ``_hog_normalize_block`` does it, in float64 and with its divisions."""
    total = 0.0
    if norm_code <= 1:
        for v in block:
            total += abs(v)
        block /= total + eps
        if norm_code == 1:
            block[:] = np.sqrt(block)
        return
    for v in block:
        total += v * v
    block /= np.sqrt(total + eps * eps)
    if norm_code == 3:
        total = 0.0
        for i in range(block.size):
            block[i] = min(block[i], 0.2)
            total += block[i] * block[i]
        block /= np.sqrt(total + eps * eps)


@njit(cache=True, nogil=True)
def _normalize_blocks_f64(cells, cpb_y, cpb_x, norm_code, eps, out):
    """The float64 path: every block gathered and normalised on its own."""
    channels, nbins = cells.shape[2], cells.shape[3]
    per_channel = cpb_y * cpb_x * nbins
    for by in range(out.shape[0]):
        for bx in range(out.shape[1]):
            for c in range(channels):
                block = out[by, bx, c * per_channel:(c + 1) * per_channel]
                n = 0
                for cy in range(cpb_y):
                    for cx in range(cpb_x):
                        for b in range(nbins):
                            block[n] = cells[by + cy, bx + cx, c, b]
                            n += 1
                _normalize_block_f64(block, norm_code, eps)


def normalize_blocks(cells, cells_per_block, norm, eps=EPS, parallel=False, out=None):
    """Normalise overlapping blocks of cells.

    Parameters
    ----------
    cells : ndarray of float32 or float64, shape (Hc, Wc, C, nbins)
        Cell histograms from :func:`fastdet.kernels.hog.cell_histograms`.
        float64 cells (of float64 images) are normalised in float64, block
        by block as scikit-image does; float32 cells by the vectorised
        float32 kernels.
    cells_per_block : tuple of int
        ``(cpb_y, cpb_x)``.
    norm : {'L1', 'L1-sqrt', 'L2', 'L2-Hys'}
        scikit-image's block normalisation schemes.
    eps : float
        Regulariser, as in scikit-image.
    parallel : bool
        Spread block rows over Numba's threads.
    out : ndarray, optional
        Array of the output's shape and of the cells' dtype to fill (saves
        an allocation per call).

    Returns
    -------
    ndarray of the cells' dtype, shape (Hc - cpb_y + 1, Wc - cpb_x + 1, C * cpb_y * cpb_x * nbins)
        Normalised block features, each block ordered (channel, cell_y, cell_x, bin).
        Empty (zero rows or columns) when there are fewer cells than a block.
    """
    cpb_y, cpb_x = int(cells_per_block[0]), int(cells_per_block[1])
    if norm not in NORM_CODES:
        raise ValueError(f"unknown block norm {norm!r}; expected one of {sorted(NORM_CODES)}")
    n_cells_y, n_cells_x, channels, nbins = cells.shape
    double = cells.dtype == np.float64
    out = _output(out, (max(n_cells_y - cpb_y + 1, 0), max(n_cells_x - cpb_x + 1, 0),
                        channels * cpb_y * cpb_x * nbins), np.float64 if double else np.float32)
    if out.shape[0] == 0 or out.shape[1] == 0:
        return out
    norm_code = NORM_CODES[norm]
    if double:
        _normalize_blocks_f64(np.ascontiguousarray(cells), cpb_y, cpb_x, norm_code, float(eps),
                              out)
        return out
    energy = cell_energy(cells, norm_code)
    kernel = _normalize_parallel if parallel else _normalize_serial
    kernel(cells, energy, cpb_y, cpb_x, norm_code, float(eps), out)
    return out
