"""Whole-image gradient orientation histograms (the cell stage of HOG).

The gradient, orientation binning and cell pooling follow scikit-image's
``hog`` exactly, so that features match ``skimage.feature.hog`` to float32
rounding:

* gradients are central differences ``I[y+1] - I[y-1]`` and ``I[x+1] - I[x-1]``
  with zero gradient on the outermost rows / columns of the image;
* orientations are unsigned (0-180 degrees) and binned *hard*: bin ``i`` holds
  angles in ``[i * 180 / nbins, (i + 1) * 180 / nbins)``;
* a cell's histogram is the mean gradient magnitude per bin over its
  ``ppc_y * ppc_x`` pixels; pixels beyond the last whole cell are ignored.

Three paths compute the bins, each agreeing with scikit-image bin for bin:

* uint8 images with 9 bins, 8x8 cells and 1 or 3 channels (the default
  model): a block of LLVM vector code per two cells keeps the per-bin sums in
  registers; the bin comes from comparisons with the boundaries' tangents, a
  rule checked against the lookup table below for every integer gradient
  before first use (sums may differ from the other paths in float32 order);
* other uint8 images: a lookup table of the bin of every integer gradient,
  built with scikit-image's own float64 expression, and a scattered add;
* float32 images (and other dtypes, converted to float32): the number of
  boundaries the folded gradient lies past (sign tests of cross products),
  with the exact float64 ``atan2`` rule for vectors within float32 rounding
  of a boundary;
* float64 images: scikit-image's own computation, NumPy expressions and all
  (:mod:`fastdet.kernels.hog_float64`), so they agree to the last bit.

Cells come out as ``(Hc, Wc, C, nbins)`` or, for the detector's window
scoring, in the *phase layout* of a window step (:func:`phase_layout_shape`).
"""

import functools
import hashlib
import math
import os
import zipfile

import numba
import numpy as np
from llvmlite import ir
from numba import njit, prange, types, uint64
from numba.core import cgutils
from numba.extending import intrinsic

from ._llvm import HAVE_AVX2, HAVE_AVX512F, HAVE_FMA, load_vector, store_vector
from .alloc import empty
from .cache import kernel_cache_dir
from .hog_float64 import float64_cell_histograms
from .inner import CALLED_FROM_KERNELS_ONLY
from .views import flat as flat_view

# A gradient whose cross product with a bin boundary is below this fraction of
# its magnitude is re-binned with the exact atan2 rule.  float32 rounding of
# the cross product is ~1e-7 relative; 1e-4 leaves a wide margin.
_NEAR_BOUNDARY = np.float32(1e-4)

# How the float path treats channels: separately, or merged per pixel by the
# largest magnitude compared in float64 or in float32 (see _histogram_cell_row).
_SEPARATE, _MERGE_FLOAT64, _MERGE_FLOAT32 = 0, 1, 2


def orientation_tables(nbins):
    """Boundary directions and exact boundary angles for ``nbins`` bins.

    Parameters
    ----------
    nbins : int
        Number of unsigned orientation bins.

    Returns
    -------
    cos_sin : ndarray of float32, shape (nbins + 1, 2)
        ``cos`` and ``sin`` of each boundary angle ``k * 180 / nbins``,
        computed in float64 (so that 90 degrees keeps a positive cosine).
    bounds : ndarray of float64, shape (nbins + 1,)
        Boundary angles in degrees, computed as scikit-image computes them
        (``180. / nbins * i`` in double precision).
    """
    angles = np.array([180.0 / nbins * i for i in range(nbins + 1)], dtype=np.float64)
    radians = np.deg2rad(angles)
    cos_sin = np.stack([np.cos(radians), np.sin(radians)], axis=1).astype(np.float32)
    return cos_sin, angles


@njit(cache=True, nogil=True, inline="always")
def _exact_bin(gx, gy, bounds, nbins):
    """scikit-image's rule: float64 atan2 in degrees modulo 180, then bounds."""
    angle = np.arctan2(np.float64(gy), np.float64(gx)) * (180.0 / np.pi) % 180.0
    for b in range(nbins):
        if angle >= bounds[b] and angle < bounds[b + 1]:
            return b
    return -1  # angle rounded to exactly 180: scikit-image drops the pixel


@njit(cache=True, nogil=True)
def _gradient_row(image, y, channel, gx, gy):
    """Central-difference gradients of one image row, zero at the borders."""
    height, width = image.shape[0], image.shape[1]
    if 0 < y < height - 1:
        for x in range(width):
            gy[x] = image[y + 1, x, channel] - image[y - 1, x, channel]
    else:
        for x in range(width):
            gy[x] = 0.0
    gx[0] = 0.0
    gx[width - 1] = 0.0
    for x in range(1, width - 1):
        gx[x] = image[y, x + 1, channel] - image[y, x - 1, channel]


@njit(cache=True, nogil=True)
def _bin_row(gx, gy, count, cos_sin, bounds, nbins, magnitude, bins):
    """Magnitude and orientation bin of ``count`` gradients."""
    for x in range(count):
        vx = gx[x]
        vy = gy[x]
        # Fold to the upper half plane: unsigned orientation in [0, 180).
        if vy < 0.0 or (vy == 0.0 and vx < 0.0):
            vx = -vx
            vy = -vy
        mag = np.sqrt(vx * vx + vy * vy)
        magnitude[x] = mag
        b = 0
        nearest = np.float32(np.inf)
        for k in range(1, nbins):
            cross = cos_sin[k, 0] * vy - cos_sin[k, 1] * vx
            if cross >= 0.0:
                b += 1
            if abs(cross) < nearest:
                nearest = abs(cross)
        if nearest <= _NEAR_BOUNDARY * mag and mag > 0.0:
            b = _exact_bin(gx[x], gy[x], bounds, nbins)
        bins[x] = b


@njit(cache=True, nogil=True)
def _histogram_cell_row(image, cell_row, ppc_y, ppc_x, ncx, nbins, merge_mode,
                        cos_sin, bounds, out):
    """Fill ``out[cell_row]`` (shape (ncx, C_out, nbins))."""
    width = image.shape[1]
    channels = image.shape[2]
    used = ncx * ppc_x
    gx = empty(width, dtype=np.float32)
    gy = empty(width, dtype=np.float32)
    best_gx = empty(width, dtype=np.float32)
    best_gy = empty(width, dtype=np.float32)
    best_sq = empty(width, dtype=np.float64)
    magnitude = empty(width, dtype=np.float32)
    bins = empty(width, dtype=np.int64)
    row_out = out[cell_row]
    row_out[:] = 0.0
    scale = np.float32(1.0 / (ppc_y * ppc_x))
    for y in range(cell_row * ppc_y, (cell_row + 1) * ppc_y):
        if merge_mode != _SEPARATE:
            # scikit-image's multichannel rule: per pixel, the channel with the
            # largest gradient magnitude (first one on ties).  Magnitudes are
            # compared as hypot in the precision scikit-image works in (float64
            # for integer images, float32 for float32 ones), because ties and
            # near-ties decide the channel and differ between precisions.
            for c in range(channels):
                _gradient_row(image, y, c, gx, gy)
                for x in range(used):
                    if merge_mode == _MERGE_FLOAT32:
                        sq = np.float64(np.hypot(gx[x], gy[x]))
                    else:
                        sq = math.hypot(np.float64(gx[x]), np.float64(gy[x]))
                    if c == 0 or sq > best_sq[x]:
                        best_sq[x] = sq
                        best_gx[x] = gx[x]
                        best_gy[x] = gy[x]
            _bin_row(best_gx, best_gy, used, cos_sin, bounds, nbins, magnitude, bins)
            for x in range(used):
                b = bins[x]
                if b >= 0:
                    row_out[x // ppc_x, 0, b] += magnitude[x]
        else:
            for c in range(channels):
                _gradient_row(image, y, c, gx, gy)
                _bin_row(gx, gy, used, cos_sin, bounds, nbins, magnitude, bins)
                for x in range(used):
                    b = bins[x]
                    if b >= 0:
                        row_out[x // ppc_x, c, b] += magnitude[x]
    for cx in range(ncx):
        for c in range(row_out.shape[1]):
            for b in range(nbins):
                row_out[cx, c, b] *= scale


@njit(cache=True, nogil=True)
def _cell_histograms_serial(image, ppc_y, ppc_x, nbins, merge_mode, cos_sin, bounds, out):
    for cell_row in range(out.shape[0]):
        _histogram_cell_row(image, cell_row, ppc_y, ppc_x, out.shape[1], nbins,
                            merge_mode, cos_sin, bounds, out)


@njit(cache=True, parallel=True)
def _cell_histograms_parallel(image, ppc_y, ppc_x, nbins, merge_mode, cos_sin, bounds, out):
    for cell_row in prange(out.shape[0]):
        _histogram_cell_row(image, cell_row, ppc_y, ppc_x, out.shape[1], nbins,
                            merge_mode, cos_sin, bounds, out)


#: Integer gradients of uint8 images lie in [-255, 255] on both axes.
_GRAD_SPAN = 511
#: Most bins the uint8 paths take: the lookup table's 8-bit entries hold every bin
#: and the mark ``nbins`` of a dropped pixel.  Above, uint8 images take the float64 path.
LUT_MAX_BINS = 255


def orientation_lut(nbins):
    """Orientation bin of every integer gradient of a uint8 image.

    Built with scikit-image's own float64 expression, so uint8 images are
    binned exactly as ``skimage.feature.hog`` bins them, boundary cases
    included.

    Parameters
    ----------
    nbins : int

    Returns
    -------
    ndarray of uint8, shape (511 * 511,)
        Entry ``(gy + 255) * 511 + (gx + 255)`` is the bin of gradient
        ``(gx, gy)``, or ``nbins`` for the rare angle that rounds to exactly
        180 degrees (scikit-image drops those pixels).
    """
    if not 1 <= nbins <= LUT_MAX_BINS:
        raise ValueError(f"an 8-bit orientation table holds 1..{LUT_MAX_BINS} bins, got {nbins}")
    g = np.arange(-255, 256, dtype=np.float64)
    gy, gx = np.meshgrid(g, g, indexing="ij")
    angle = np.arctan2(gy, gx) * (180 / np.pi) % 180
    _, bounds = orientation_tables(nbins)
    bins = np.searchsorted(bounds, angle.ravel(), side="right") - 1
    bins[(bins < 0) | (bins >= nbins)] = nbins
    # 8-bit entries keep the table (255 KiB) in L2 cache.
    return bins.astype(np.uint8)


@njit(cache=True, nogil=True)
def _histogram_cell_row_u8(image, cell_row, ppc_y, ppc_x, ncx, nbins, bin_lut, target, index,
                           magnitude, acc, layout, out):
    """uint8 path for one cell row: gradient -> table index, then table -> histogram.

    A row is read as one flat run of ``W * C`` bytes, so the x-gradient of
    element ``j`` is ``row[j + C] - row[j - C]`` and the first pass is a
    contiguous, vectorised loop.  Indices are unsigned: Numba's negative-index
    wraparound would otherwise stop LLVM from vectorising.  The second pass
    looks up bin and magnitude of each gradient and adds into ``acc``;
    ``target[j]`` is the histogram slot base of element ``j`` (channels of a
    pixel interleave, so consecutive updates rarely hit the same slot).
    """
    height, width, channels = image.shape
    flat = image.reshape(height, width * channels)
    used = uint64(ncx * ppc_x * channels)
    c64 = uint64(channels)
    # Elements with both x-neighbours; the first and last pixel have gx = 0.
    interior_end = min(used, uint64((width - 1) * channels))
    slots = nbins + 1
    acc[:] = 0.0
    for y in range(cell_row * ppc_y, (cell_row + 1) * ppc_y):
        mid = flat[y]
        # On the first and last rows gy = 0, as in scikit-image.
        up = flat[y - 1] if y > 0 and y < height - 1 else mid
        down = flat[y + 1] if y > 0 and y < height - 1 else mid
        for j in range(uint64(0), min(c64, used)):
            gy = np.int32(down[j]) - np.int32(up[j])
            index[j] = (gy + 255) * _GRAD_SPAN + 255
            magnitude[j] = abs(np.float32(gy))
        for j in range(c64, interior_end):
            gy = np.int32(down[j]) - np.int32(up[j])
            gx = np.int32(mid[j + c64]) - np.int32(mid[j - c64])
            index[j] = (gy + 255) * _GRAD_SPAN + (gx + 255)
            magnitude[j] = np.sqrt(np.float32(gx * gx + gy * gy))
        for j in range(max(interior_end, c64), used):
            gy = np.int32(down[j]) - np.int32(up[j])
            index[j] = (gy + 255) * _GRAD_SPAN + 255
            magnitude[j] = abs(np.float32(gy))
        for j in range(used):
            acc[uint64(target[j] + bin_lut[uint64(index[j])])] += magnitude[j]
    scale = np.float32(1.0 / (ppc_y * ppc_x))
    row_base = uint64(cell_row) * layout[0]
    for cx in range(uint64(ncx)):
        position = (cx % layout[4]) * layout[5] + cx // layout[4]
        for c in range(c64):
            base = (cx * c64 + c) * uint64(slots)
            dest = row_base + position * layout[1] + c * layout[2]
            for b in range(uint64(nbins)):
                out[dest + b * layout[3]] = acc[base + b] * scale


@njit(cache=True, nogil=True)
def _slot_targets(ncx, ppc_x, channels, nbins):
    """Histogram slot base of every element of a flat row (pixel-major)."""
    used = ncx * ppc_x * channels
    target = empty(used, dtype=np.int32)
    for j in range(used):
        target[j] = ((j // channels // ppc_x) * channels + j % channels) * (nbins + 1)
    return target


@njit(cache=True, nogil=True)
def _cell_rows_u8(image, first, stop, ppc_y, ppc_x, nbins, bin_lut, ncx, layout, out):
    """Cell rows ``first`` .. ``stop - 1`` with one set of scratch buffers."""
    channels = image.shape[2]
    target = _slot_targets(ncx, ppc_x, channels, nbins)
    index = empty(target.size, dtype=np.int32)
    magnitude = empty(target.size, dtype=np.float32)
    acc = empty(ncx * channels * (nbins + 1), dtype=np.float32)
    for cell_row in range(first, stop):
        _histogram_cell_row_u8(image, cell_row, ppc_y, ppc_x, ncx, nbins, bin_lut, target,
                               index, magnitude, acc, layout, out)


@njit(cache=True, parallel=True)
def _cell_histograms_u8_parallel(image, ppc_y, ppc_x, nbins, bin_lut, bands, rows, ncx, layout,
                                 out):
    # One contiguous band of cell rows per thread keeps scratch set-up rare.
    for band in prange(bands):
        _cell_rows_u8(image, band * rows // bands, (band + 1) * rows // bands, ppc_y, ppc_x,
                      nbins, bin_lut, ncx, layout, out)


@njit(cache=True, nogil=True)
def _standard_to_phase(cells, layout, out):
    """Copy (Hc, Wc, C, nbins) cells into the flat phase layout ``layout``."""
    rows, ncx, channels, nbins = cells.shape
    for cy in range(uint64(rows)):
        for cx in range(uint64(ncx)):
            position = (cx % layout[4]) * layout[5] + cx // layout[4]
            for c in range(uint64(channels)):
                dest = cy * layout[0] + position * layout[1] + c * layout[2]
                for b in range(uint64(nbins)):
                    out[dest + b * layout[3]] = cells[cy, cx, c, b]


def phase_layout_shape(cells_y, cells_x, channels, nbins, step, pad):
    """Shape of the phase layout of a ``(cells_y, cells_x)`` cell grid.

    In the phase layout, cell column ``cx`` sits at position
    ``(cx % step) * K + cx // step`` (``K = ceil(cells_x / step)``) of the
    last axis: the columns of each phase ``cx % step`` are contiguous, so
    the blocks of windows stepped by ``step`` cells are too.  ``pad`` zero
    positions follow, for kernels that read a few columns past a phase.

    Returns
    -------
    tuple of int
        ``(cells_y, channels, nbins, step * K + pad)``.
    """
    per_phase = -(-cells_x // step)
    return (cells_y, channels, nbins, step * per_phase + pad)


def to_phase_layout(cells, step, pad=0):
    """Copy ``(Hc, Wc, C, nbins)`` cells into the phase layout for ``step``.

    Returns
    -------
    ndarray of float32, shape ``phase_layout_shape(Hc, Wc, C, nbins, step, pad)``
    """
    rows, cells_x, channels, nbins = cells.shape
    phase = np.zeros(phase_layout_shape(rows, cells_x, channels, nbins, step, pad), np.float32)
    if phase.size and cells.size:
        _standard_to_phase(np.ascontiguousarray(cells, dtype=np.float32),
                           _layout(phase.shape, step, cells_x), phase.reshape(-1))
    return phase


@functools.lru_cache(maxsize=256)
def _layout(shape, phase_step=None, cells_x=None):
    """Flat-index strides of a cell array: (row, position, channel, bin, step, K).

    Cell ``(cy, cx, c, b)`` lives at ``cy * row + pos(cx) * position +
    c * channel + b * bin`` with ``pos(cx) = (cx % step) * K + cx // step``.
    ``shape`` is ``(Hc, Wc, C, nbins)``, or the phase layout's shape when
    ``phase_step`` is given (then ``cells_x`` is the grid's ``Wc``).
    """
    if phase_step is None:
        rows, ncx, channels, nbins = shape
        strides = (ncx * channels * nbins, channels * nbins, nbins, 1, 1, ncx)
    else:
        rows, channels, nbins, length = shape
        strides = (channels * nbins * length, 1, nbins * length, length, phase_step,
                   -(-cells_x // phase_step))
    # Cached (the same few shapes every frame): read-only, shared.
    layout = np.array(strides, dtype=np.uint64)
    layout.flags.writeable = False
    return layout


def cell_histograms(image, pixels_per_cell, nbins, merge_channels=False, parallel=False, out=None,
                    phase_step=None, phase_pad=0, rows=None, keep_unmapped=False):
    """Per-cell histograms of unsigned gradient orientation.

    Parameters
    ----------
    image : ndarray, shape (H, W, C)
        Image; each channel is treated independently unless
        ``merge_channels`` is set.  uint8 images take the fast exact paths
        (orientation bins from comparisons or a lookup table of all integer
        gradients; with more than :data:`LUT_MAX_BINS` bins the float64
        path, the cells still float32); float64 images are computed exactly
        as scikit-image computes them (:mod:`fastdet.kernels.hog_float64`,
        serial) and give float64 cells; other dtypes are converted to float32.
    pixels_per_cell : tuple of int
        ``(ppc_y, ppc_x)``.
    nbins : int
        Number of orientation bins over 0-180 degrees.
    merge_channels : bool
        Use, per pixel, the gradient of the channel with the largest
        magnitude (scikit-image's ``channel_axis`` behaviour); the output then
        has a single channel.
    parallel : bool
        Spread cell rows over Numba's threads.
    out : ndarray, optional
        Array of the output's shape and dtype to fill (saves an allocation
        per call).
    phase_step : int, optional
        Return the cells in the phase layout of :func:`phase_layout_shape`
        for windows stepped by this many cells (what
        :func:`fastdet.kernels.score.add_hog_scores_from_phase_cells` reads)
        instead of ``(Hc, Wc, C, nbins)``.
    phase_pad : int
        Zero positions after the last phase (phase layout only).
    rows : tuple of int, optional
        ``(first, stop)``: fill only these cell rows of ``out`` (uint8
        images in the phase layout; the other rows are left as they are).
        Threads compute bands of one image this way.
    keep_unmapped : bool
        Leave the positions of ``out`` that no cell maps to (phase layout:
        the ends of short phases, the padding) as they are instead of
        zeroing them: for a caller that keeps them zero itself, as the
        detector does with its reused, zero-initialised arrays.  Zeroing them
        costs a scale about 20 us with the GIL held.

    Returns
    -------
    ndarray of float32 (float64 for float64 images), shape (H // ppc_y, W // ppc_x, C_out, nbins)
        Mean gradient magnitude per orientation bin of each cell (or the
        phase layout of the same values, always float32).
    """
    ppc_y, ppc_x = int(pixels_per_cell[0]), int(pixels_per_cell[1])
    if not isinstance(image, np.ndarray) or image.ndim != 3:
        raise ValueError(f"expected an (H, W, C) image array, got {getattr(image, 'shape', image)!r}")
    # The kernels read rows as flat runs.
    image = np.ascontiguousarray(image)
    height, width, channels = image.shape
    if image.dtype == np.uint8 and nbins > LUT_MAX_BINS:
        # Past the table's 8-bit bins: the values scikit-image gives, as float32.
        if rows is not None:
            raise ValueError(f"rows: uint8 cells of at most {LUT_MAX_BINS} bins, got {nbins}")
        cells = cell_histograms(image.astype(np.float64), pixels_per_cell, nbins,
                                merge_channels).astype(np.float32)
        if phase_step is not None:
            cells = to_phase_layout(cells, int(phase_step), int(phase_pad))
        if out is None:
            return cells
        _output(out, cells.shape)[...] = cells
        return out
    out_channels = 1 if merge_channels else channels
    cells_y, cells_x = height // ppc_y, width // ppc_x
    shape = (cells_y, cells_x, out_channels, nbins)
    if phase_step is not None:
        if int(phase_step) < 1 or int(phase_pad) < 0:
            raise ValueError(f"phase_step must be >= 1 and phase_pad >= 0, "
                             f"got {phase_step!r}, {phase_pad!r}")
        phase_step = int(phase_step)
        phase_shape = phase_layout_shape(cells_y, cells_x, out_channels, nbins, phase_step,
                                         int(phase_pad))
        if not (image.dtype == np.uint8 and not merge_channels):
            phase = to_phase_layout(cell_histograms(image, pixels_per_cell, nbins,
                                                    merge_channels, parallel),
                                    phase_step, int(phase_pad))
            if out is None:
                return phase
            _output(out, phase_shape)[...] = phase
            return out
        out = _output(out, phase_shape)
        first, stop = (0, cells_y) if rows is None else (max(0, int(rows[0])),
                                                         min(cells_y, int(rows[1])))
        if out.size and first < stop:
            if not keep_unmapped:
                _zero_unmapped(out[first:stop], cells_x, phase_step)
            _u8_cells(image, ppc_y, ppc_x, nbins, parallel, first, stop, cells_x,
                      _layout(phase_shape, phase_step, cells_x), out.reshape(-1))
        return out
    out = _output(out, shape, np.float64 if image.dtype == np.float64 else np.float32)
    if out.size == 0:
        return out
    if image.dtype == np.uint8 and not merge_channels:
        _u8_cells(image, ppc_y, ppc_x, nbins, parallel, 0, cells_y, cells_x, _layout(shape),
                  out.reshape(-1))
        return out
    cos_sin, bounds = _tables(nbins)
    kernel = _cell_histograms_parallel if parallel else _cell_histograms_serial
    merge_mode = _SEPARATE
    if merge_channels:
        merge_mode = _MERGE_FLOAT32 if image.dtype == np.float32 else _MERGE_FLOAT64
    if image.dtype == np.float64:
        return float64_cell_histograms(image, ppc_y, ppc_x, nbins, merge_channels, bounds, out)
    kernel(np.asarray(image, dtype=np.float32), ppc_y, ppc_x, nbins, merge_mode,
           cos_sin, bounds, out)
    return out


class PhaseCellRows:
    """:func:`cell_histograms` of uint8 images of one shape into one phase-layout
    array, checked and sized once; each call computes some cell rows.

    For the detector's scales (see :class:`~fastdet.kernels.score.WindowRowScorer`).
    Like ``cell_histograms(..., keep_unmapped=True)``, the positions of
    ``out`` that no cell maps to are left as they are: keep them zero.

    Parameters
    ----------
    image_shape : tuple of int
        ``(H, W, C)`` of the uint8 images the calls take.
    pixels_per_cell : tuple of int
    nbins : int
    out : ndarray of float32
        C-contiguous, of :func:`phase_layout_shape` for the image's cell grid.
    phase_step : int
    phase_pad : int

    Attributes
    ----------
    out : ndarray of float32
        The phase-layout cell histograms the calls fill.
    kernel : numba dispatcher
        The cell kernel the calls run (:meth:`call` gives its arguments), for
        kernels that call it themselves (:class:`fastdet.kernels.band.BandScorer`).
    pixels_per_cell : tuple of int
        ``(rows, columns)`` of one cell.
    cells_y : int
        Cell rows of the images.
    """

    def __init__(self, image_shape, pixels_per_cell, nbins, out, phase_step, phase_pad):
        height, width, channels = (int(n) for n in image_shape)
        ppc_y, ppc_x = int(pixels_per_cell[0]), int(pixels_per_cell[1])
        nbins, phase_step, phase_pad = int(nbins), int(phase_step), int(phase_pad)
        if phase_step < 1 or phase_pad < 0:
            raise ValueError(f"phase_step must be >= 1 and phase_pad >= 0, "
                             f"got {phase_step!r}, {phase_pad!r}")
        self.image_shape = (height, width, channels)
        self.pixels_per_cell = (ppc_y, ppc_x)
        self.cells_y, cells_x = height // ppc_y, width // ppc_x
        shape = phase_layout_shape(self.cells_y, cells_x, channels, nbins, phase_step,
                                   phase_pad)
        self.out = _output(out, shape)
        self._out_flat = self.out.reshape(-1)
        self.kernel, self._args = _serial_cell_rows(ppc_y, ppc_x, nbins, channels, cells_x,
                                                     _layout(shape, phase_step, cells_x),
                                                     self._out_flat)

    def __call__(self, image, first, stop):
        """Compute cell rows ``first`` .. ``stop - 1`` of ``image`` into :attr:`out`."""
        call = self.call(image, first, stop)
        if call is not None:
            call[0](*call[1])

    def call(self, image, first, stop):
        """``(kernel, arguments)`` of what :meth:`__call__` runs, or None when it
        computes nothing (no rows, or no cells)."""
        if (image.shape != self.image_shape or image.dtype != np.uint8
                or not image.flags.c_contiguous):
            raise ValueError(f"expected a C-contiguous uint8 image of shape {self.image_shape}, "
                             f"got {image.dtype} {image.shape}")
        first, stop = max(0, int(first)), min(self.cells_y, int(stop))
        if first >= stop or not self._out_flat.size:
            return None
        return self.kernel, (image, first, stop, *self._args)


def _zero_unmapped(phase, cells_x, step):
    """Zero the positions of phase-layout cells that no cell column maps to:
    the end of each phase shorter than the longest, and the padding.  Every
    other position is written by the cell kernels."""
    per_phase = -(-cells_x // step)
    for q in range(min(step, cells_x)):
        filled = -(-(cells_x - q) // step)
        phase[..., q * per_phase + filled:(q + 1) * per_phase] = 0.0
    phase[..., min(step, cells_x) * per_phase:] = 0.0


def _u8_cells(image, ppc_y, ppc_x, nbins, parallel, first, stop, cells_x, layout, out_flat):
    """Cell rows ``first`` .. ``stop - 1`` of a uint8 image into ``out_flat``."""
    bands = min(numba.get_num_threads(), stop - first) if parallel and first == 0 else 1
    if bands <= 1:
        kernel, args = _serial_cell_rows(ppc_y, ppc_x, nbins, image.shape[2], cells_x, layout,
                                         out_flat)
        kernel(image, first, stop, *args)
    elif _fast_path(ppc_y, ppc_x, nbins, image.shape[2]):
        _cell_histograms_u8_fast_parallel(image, _bin_lut(nbins), bands, stop, cells_x, layout,
                                          out_flat)
    else:
        _cell_histograms_u8_parallel(image, ppc_y, ppc_x, nbins, _bin_lut(nbins), bands, stop,
                                     cells_x, layout, out_flat)


def _fast_path(ppc_y, ppc_x, nbins, channels):
    """Whether uint8 cells of these settings take the vector path."""
    return ((ppc_y, ppc_x, nbins) == _FAST_PPC + (_FAST_NBINS,) and channels in _FAST_CHANNELS
            and _fast_rule_ok())


def _serial_cell_rows(ppc_y, ppc_x, nbins, channels, cells_x, layout, out_flat):
    """``(kernel, args)``: ``kernel(image, first, stop, *args)`` computes uint8 cell rows."""
    bin_lut = _bin_lut(nbins)
    if _fast_path(ppc_y, ppc_x, nbins, channels):
        # None: three channels, compiled alone (see _cell_rows_u8_fast).
        fast = (bin_lut, cells_x, layout, out_flat, None if channels == 3 else channels)
        if cells_x % _GROUP_CELLS == 0:
            return _cell_rows_u8_fast, fast
        return _fast_cell_rows_and_tail, (fast, (bin_lut, cells_x, layout, out_flat))
    return _cell_rows_u8, (ppc_y, ppc_x, nbins, bin_lut, cells_x, layout, out_flat)


def _fast_cell_rows_and_tail(image, first, stop, fast, tail):
    """The vector kernel's cells, then the last cell column of an odd grid."""
    _cell_rows_u8_fast(image, first, stop, *fast)
    _cell_rows_u8_tail(image, first, stop, *tail)


@functools.lru_cache(maxsize=None)
def _tables(nbins):
    return orientation_tables(nbins)


def _lut_path(nbins):
    return kernel_cache_dir() / f"orientation-lut-{nbins}-numpy-{np.__version__}.npz"


def _digest(lut):
    return np.frombuffer(hashlib.sha256(lut.tobytes()).digest(), dtype=np.uint8)


@functools.lru_cache(maxsize=None)
def _bin_lut(nbins):
    """:func:`orientation_lut`, kept beside the compiled kernels.

    Building it (a float64 ``arctan2`` of 261,121 gradients) took 23 ms of
    every process's first detection; the saved copy loads in about 1 ms.  It
    is keyed by NumPy's version (whose ``arctan2`` defines it) and written
    atomically with its SHA-256, which is checked on loading: a damaged copy
    is rebuilt, never used.  An unwritable cache folder only means it is
    rebuilt every time.
    """
    path = _lut_path(nbins)
    try:
        with np.load(path, allow_pickle=False) as saved:
            lut, digest = saved["lut"], saved["sha256"]
        if (lut.shape == (_GRAD_SPAN * _GRAD_SPAN,) and lut.dtype == np.uint8
                and np.array_equal(digest, _digest(lut))):
            return lut
    except (OSError, ValueError, KeyError, zipfile.BadZipFile):
        pass
    lut = orientation_lut(nbins)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        partial = path.with_name(f"{path.name}.{os.getpid()}.part")
        with open(partial, "wb") as handle:
            np.savez(handle, lut=lut, sha256=_digest(lut))
        os.replace(partial, path)
    except OSError:
        pass
    return lut


def _output(out, shape, dtype=np.float32):
    """``out`` checked against ``shape`` and ``dtype``, or a new array."""
    dtype = np.dtype(dtype)
    if out is None:
        return np.empty(shape, dtype=dtype)
    if out.shape != shape or out.dtype != dtype or not out.flags.c_contiguous:
        raise ValueError(f"out must be a C-contiguous {dtype} array of shape {shape}, "
                         f"got {out.dtype} {out.shape}")
    return out


# -- the vector path: per-bin accumulators in vector registers ----------------
#
# For the default configuration (nbins 9, 8x8 cells, 1 or 3 channels) a cell
# row is processed in groups of _GROUP_CELLS cells (G = 2 * 8 * C elements of
# the flat row, whole vectors of _LANES lanes: 16 with AVX-512, 8 with AVX2,
# 4 otherwise).  For each piece of _LANES elements of a group, one block of
# LLVM vector IR walks the cell row's 8 image rows, computes the gradients and
# the exact float32 magnitude of its elements at once.  The bin rule below is
# a count of nested threshold conditions, so instead of a bin per element the
# block keeps nbins + 1 vector accumulators: the magnitudes of acute and of
# obtuse elements, over all elements and over those past each threshold (two
# masked adds per threshold); they stay in registers for the 8 rows.
# Afterwards neighbouring accumulators are subtracted into bins lane by lane,
# a planned tree of two-source shuffles and adds sums each (bin, cell,
# channel)'s pixels (_reduction_plan: all bins share the shuffles), and the
# block stores the cell means.  This replaces the per-element table lookup and
# memory scatter of the general uint8 path.  Cells that do not fill a whole
# group are done one element at a time with the lookup table.
#
# Measured on the detector's five scales of a 1280x720 frame (1.1 M pixels,
# 3 channels, one thread, min of 60 runs): with AVX2 (NUMBA_CPU_NAME=haswell
# NUMBA_CPU_FEATURES=) 16-lane pieces spilled their accumulators (1132 stack
# moves in the kernel) and took 3.45-3.71 ms; 8 lanes with AND-then-add 2.6 ms.
# With AVX-512 the shuffle tree instead of per-bin reductions changed little
# (1.77-1.84 -> 1.69-1.73 ms): the row loop dominates.
#
# Without AVX-512 that loop is bound by latency, not by its instructions
# (AMD EPYC, Zen 3): llvm-mca -mcpu=znver3 finds its 4-port throughput at 9.5
# cycles per 8 lanes but simulates 19, the floating-point scheduler (64
# entries) full in 80 % of cycles with operations waiting on each row's
# loads, conversions and square root; the same loop in C took 19.5 cycles.
# Computing the whole group's gradients first, into a 6 KB stack buffer, and
# then each piece's sums from it (two_pass) took 15.1 cycles in C; in the
# kernel, cell_histograms of a frame's five scaled HLS images took 1.67-1.69
# ms against 1.91 (8 lanes) and 6.1 against 7.25 ms (4 lanes,
# NUMBA_CPU_NAME=generic), bit-identical.
#
# What is left on AVX2 (AMD EPYC, Zen 3, 2026-12-02, the interior blocks over
# a whole 1280x720 HLS frame): 18.5-19.3 cycles per 8 lanes, of which the
# gradient pass takes about 9 (the sums replaced by two adds: 9.0) and the
# square root 1.4 (replaced by its argument: 17.5).  The sums loop is 26
# vector operations per 8 lanes and row (4 multiplies, 4 compares, 8 ANDs, 10
# adds) and ran at about 3 a cycle.  Making each threshold's 0.0 / 1.0 unit
# once and fusing both of its masked adds into multiply-adds (_FUSED_ADD; 5
# operations a threshold instead of 6, the adds moved to the multiply units)
# took 0.93-0.97x the time, bit-identical; fusing only one or two of the four
# thresholds took 1.00x and 1.13x.
#
# The bin comes from a rule, not the table: with ax = |gx|, ay = |gy| and
# t_k = float32(tan(k * 180 / nbins deg)), k' = number of k (1 .. nbins // 2)
# with ay >= float32(ax * t_k); the bin is nbins - 1 - k' if gx * gy < 0, else
# k'.  It is checked against orientation_lut over every integer gradient
# before first use (_fast_rule_ok); if it ever disagreed, the table path runs.

_FAST_NBINS = 9
_FAST_PPC = (8, 8)
_FAST_CHANNELS = (1, 3)
_GROUP_CELLS = 2
#: Lanes of a piece: the accumulators (nbins + 1 vectors) must stay in
#: registers over a cell's rows.  AVX-512 has 32 zmm registers, so 16 float
#: lanes; AVX2 has 16 ymm registers, too few for ten 16-lane (two-register)
#: accumulators, so 8; plain SSE 16 xmm registers, so 4.
_LANES = 16 if HAVE_AVX512F else 8 if HAVE_AVX2 else 4
#: Masked adds as an AND of the value, then an add (see the block's
#: masked_add): where there is no AVX-512 masked add.
_MASK_THEN_ADD = not HAVE_AVX512F
#: Masked adds as a fused multiply-add of the value and 0.0 or 1.0 (see the
#: block's masked_add): without AVX-512's masked add, where there is FMA.
_FUSED_ADD = _MASK_THEN_ADD and HAVE_FMA
#: Gradients of the whole group first, then the sums (see the block's
#: two_pass), on every CPU.  Without AVX-512 two passes took 0.72-0.80x the
#: time of one (Zen 3, Zen 4 with AVX-512 hidden, and the AVX2 build on a
#: Zen 5).  With AVX-512 they took 0.78-0.80x on an AMD Zen 5 (CPU family 26,
#: model 2; asv CellBlockOrders alternating in one process, medians of the
#: per-round ratios over 60-100 rounds, 2026-12-04) and the same time on a
#: Zen 4 (per-round ratio 1.00-1.01, two passes' minima lower); llvm-mca
#: predicts no change for Intel's cores, whose schedulers are shared by all
#: ports.  Both orders give the same sums, bit for bit.
_TWO_PASS = True


def _fast_thresholds(nbins):
    """float32 tangents of the bin boundaries below 90 degrees (odd nbins)."""
    return [float(np.float32(math.tan(math.radians(180.0 / nbins * k))))
            for k in range(1, (nbins - 1) // 2 + 1)]


def threshold_bins(gx, gy, nbins):
    """Orientation bins of integer gradient arrays by the threshold rule.

    ``nbins`` must be odd.  Equals ``orientation_lut(nbins)`` for every integer
    gradient of a uint8 image except (0, 0), whose magnitude is zero (see
    :func:`_fast_rule_ok`).
    """
    gx = np.asarray(gx, dtype=np.int64)
    gy = np.asarray(gy, dtype=np.int64)
    ax, ay = np.abs(gx).astype(np.float32), np.abs(gy).astype(np.float32)
    k = np.zeros(np.broadcast(gx, gy).shape, dtype=np.int64)
    for t in _fast_thresholds(nbins):
        # float32 product, as the vector kernel computes it.
        k += ay >= ax * np.float32(t)
    obtuse = gx * gy < 0
    return np.where(obtuse, nbins - 1 - k, k)


@functools.lru_cache(maxsize=None)
def _fast_rule_ok(nbins=_FAST_NBINS):
    """Whether the threshold rule reproduces orientation_lut(nbins) exactly.

    A pass is remembered beside the saved table (see :func:`_bin_lut`), keyed
    by the thresholds, so later processes skip the 20 ms check; a failure is
    checked every time.
    """
    key = hashlib.sha256(repr(_fast_thresholds(nbins)).encode()).hexdigest()[:16]
    passed = _lut_path(nbins).with_suffix(f".rule-{key}-ok")
    lut = _bin_lut(nbins)
    if passed.exists() and _lut_path(nbins).exists():
        return True
    g = np.arange(-255, 256)
    gy, gx = np.meshgrid(g, g, indexing="ij")
    rule = threshold_bins(gx, gy, nbins).ravel()
    nonzero = ((gx != 0) | (gy != 0)).ravel()
    ok = bool(np.array_equal(rule[nonzero], lut.astype(np.int64)[nonzero]))
    if ok:
        try:
            passed.touch()
        except OSError:
            pass
    return ok


class _ReductionPlan:
    """How a cell block adds up its per-lane bin sums (see :func:`_reduction_plan`).

    ``levels``: per level, the output vectors as ``(left, right)`` shuffles,
    each ``((first_source, second_source), mask)`` over the level's input
    vectors (``second_source`` None: one source); an output is the sum of its
    two shuffles.  ``index[(b * cells + cell) * channels + c]``: where the
    mean of bin ``b`` of (cell, channel) lands in the stored vectors;
    ``size``: how many floats they hold.
    """

    def __init__(self, levels, index, size):
        self.levels, self.index, self.size = levels, index, size


@functools.lru_cache(maxsize=None)
def _reduction_plan(lanes, channels, ppc_x, nbins):
    """Plan the pixel sums of a cell block's ``nbins`` x pieces bin vectors.

    Eight lanes and three channels (the colour HOG on AVX2) take
    :func:`_half_lane_plan`; every other block the greedy plan below.  Both
    add the same pairs in the same tree, so every plan gives the same bits.

    Lane ``l`` of piece ``q`` of a bin vector holds flat-row element
    ``e = q * lanes + l``: pixel ``(e // channels) % ppc_x`` of cell
    ``e // (channels * ppc_x)``, channel ``e % channels``.  Each level pairs
    every (bin, cell, channel, pixel p < half) with its pixel ``p + half``;
    the pairs are packed greedily into output vectors whose left and right
    operands each come from at most two input vectors (one two-source shuffle
    each).  Summing every bin's pieces separately, as a tree over a
    concatenated vector, took about five times as many shuffles.
    """
    assert ppc_x & (ppc_x - 1) == 0, "pixels per cell row must be a power of two"
    if (lanes, channels, ppc_x, _GROUP_CELLS) == (8, 3, 8, 2):
        return _half_lane_plan(nbins)
    pieces = _GROUP_CELLS * ppc_x * channels // lanes
    where = {}
    for b in range(nbins):
        for q in range(pieces):
            for lane in range(lanes):
                e = q * lanes + lane
                key = (b, e // (channels * ppc_x), e % channels)
                where[key, (e // channels) % ppc_x] = (b * pieces + q, lane)
    width = ppc_x
    levels = []
    while width > 1:
        half = width // 2
        pairs = sorted(((where[key, p], where[key, p + half]), (key, p))
                       for (key, p) in where if p < half)
        outputs, current = [], []

        def flush():
            if not current:
                return
            shuffles = []
            for side in (0, 1):
                sources = []
                for operands, _ in current:
                    if operands[side][0] not in sources:
                        sources.append(operands[side][0])
                mask = [operands[side][1] + lanes * sources.index(operands[side][0])
                        for operands, _ in current]
                mask += [0] * (lanes - len(mask))
                shuffles.append(((sources[0], sources[1] if len(sources) > 1 else None), mask))
            outputs.append((tuple(shuffles), [name for _, name in current]))
            current.clear()

        for operands, name in pairs:
            trial = current + [(operands, name)]
            if len(trial) > lanes or any(len({o[side][0] for o, _ in trial}) > 2
                                         for side in (0, 1)):
                flush()
                trial = [(operands, name)]
            current[:] = trial
        flush()
        where = {name: (v, lane) for v, (_, names) in enumerate(outputs)
                 for lane, name in enumerate(names)}
        levels.append([shuffles for shuffles, _ in outputs])
        width = half
    cells = _GROUP_CELLS
    index = np.empty(nbins * cells * channels, dtype=np.int64)
    for (b, cell, c), _ in where:
        v, lane = where[(b, cell, c), 0]
        index[(b * cells + cell) * channels + c] = v * lanes + lane
    size = (max(where.values())[0] + 1) * lanes
    return _ReductionPlan(levels, index, size)


def _half_lane_plan(nbins):
    """The pixel sums of a colour block's bins with eight lanes, bin by bin.

    A cell row of one channel's pixels is 24 elements, three vectors, and
    pixel ``p + 4`` lies 12 elements after pixel ``p``: three 128-bit halves
    on, in the same lane of its half.  So each level's operands are whole
    halves of two vectors (``vperm2f128``) or the same two-and-two lanes of
    both halves (``vshufps``), where the greedy plan's arbitrary masks took
    two or three shuffles each on AVX2, and each bin's sums need only its own
    six vectors.  Per bin, with ``h0 .. h5`` the halves of a cell's three
    vectors and ``y(e) = x(e) + x(e + 12)`` (pixel p with p + 4):

    * level 1: per half (cell), ``P = y(0..3)`` (h0 + h3), ``R = y(4..7)``
      (h1 + h4), ``Y = y(8..11)`` (h2 + h5);
    * level 2 (pixel p with p + 2): ``U = y(0..2) + y(6..8)`` (pixel 0 of
      each channel), ``V = y(3..5) + y(9..11)`` (pixel 1);
    * level 3: ``U + V`` (pixel 0 with 1), the bin's means of both cells in
      lanes 0-2 and 4-6 (lanes 3 and 7 hold sums nothing reads).

    The same pairs in the same tree as the greedy plan, so the same bits
    (``tests/kernels/test_cells_fast.py`` checks both, symbolically and on
    images).
    """
    lanes, channels = 8, 3
    low, high, same = [0, 1, 2, 3, 8, 9, 10, 11], [4, 5, 6, 7, 12, 13, 14, 15], list(range(8))
    levels = ([], [], [])
    index = np.empty(nbins * _GROUP_CELLS * channels, dtype=np.int64)
    for b in range(nbins):
        q = [b * 6 + piece for piece in range(6)]       # cell 0: q[0..2], cell 1: q[3..5]
        levels[0].extend([(((q[0], q[3]), low), ((q[1], q[4]), high)),     # P
                          (((q[0], q[3]), high), ((q[2], q[5]), low)),     # R
                          (((q[1], q[4]), low), ((q[2], q[5]), high))])    # Y
        p_, r_, y_ = 3 * b, 3 * b + 1, 3 * b + 2
        levels[1].extend([(((p_, None), same), ((r_, y_), [2, 3, 8, 8, 6, 7, 12, 12])),  # U
                          (((p_, r_), [3, 8, 9, 9, 7, 12, 13, 13]),                      # V
                           ((y_, None), [1, 2, 3, 3, 5, 6, 7, 7]))])
        levels[2].append((((2 * b, None), same), ((2 * b + 1, None), same)))
        for cell in range(_GROUP_CELLS):
            for c in range(channels):
                index[(b * _GROUP_CELLS + cell) * channels + c] = b * lanes + cell * 4 + c
    return _ReductionPlan([list(level) for level in levels], index, nbins * lanes)


def _group_block(channels, ppc_x, ppc_y, nbins, first, last, lanes=_LANES,
                 mask_then_add=_MASK_THEN_ADD, two_pass=_TWO_PASS, fused_add=_FUSED_ADD):
    """An intrinsic ``block(flat, height, row_bytes, y0, x0, scratch)``.

    Adds up, for the _GROUP_CELLS cells whose elements start at flat-row offset
    ``x0`` in image rows ``y0 .. y0 + ppc_y - 1``, the gradient magnitude per
    (bin, cell, channel) and stores the means (sums / (ppc_y * ppc_x)) to
    ``scratch[plan.index[(b * _GROUP_CELLS + cell) * channels + c]]`` of the
    ``_reduction_plan(lanes, channels, ppc_x, nbins)``.  ``first``: the group
    starts at the row's first pixel (gx = 0 there, nothing read before it);
    ``last``: it ends with the row's last pixel.  Otherwise the block reads
    ``channels`` bytes either side of the group.  ``two_pass``: the group's
    gradients go through a stack buffer before they are summed (same sums,
    bit for bit; see the comment at ``if two_pass``).  ``fused_add``: the
    masked adds as fused multiply-adds (same sums; see ``masked_add``).
    """
    group = _GROUP_CELLS * ppc_x * channels
    assert group % lanes == 0 and channels < lanes
    assert (ppc_y * ppc_x) & (ppc_y * ppc_x - 1) == 0, "the cell mean must scale exactly"
    pieces = group // lanes
    thresholds = _fast_thresholds(nbins)
    plan = _reduction_plan(lanes, channels, ppc_x, nbins)

    def codegen(context, builder, signature, args):
        i8, i32, i64, f32 = ir.IntType(8), ir.IntType(32), ir.IntType(64), ir.FloatType()
        bytes_t = ir.VectorType(i8, lanes)
        ints_t = ir.VectorType(i32, lanes)
        floats_t = ir.VectorType(f32, lanes)
        mask_t = lambda n: ir.VectorType(i32, n)  # noqa: E731
        data = context.make_array(signature.args[0])(context, builder, args[0]).data
        scratch = context.make_array(signature.args[5])(context, builder, args[5]).data
        height, row_bytes, y0, x0 = [context.cast(builder, v, t, types.int64)
                                     for v, t in zip(args[1:5], signature.args[1:5])]
        sqrt = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(floats_t, [floats_t]), f"llvm.sqrt.v{lanes}f32")

        def splat(value, vtype=ints_t):
            return ir.Constant(vtype, [value] * vtype.count)

        def load(offset):
            return load_vector(builder, data, offset, bytes_t)

        def widen(v):
            return builder.zext(v, ints_t)

        def masked_add(past, total, value, unit=None):
            # All forms give the same sums: totals are never -0.0, so adding
            # +0.0 leaves them unchanged, and value * 1.0 + total rounds as
            # value + total.  AVX-512 has a masked add (one instruction);
            # elsewhere LLVM would make the select of sums a blend (two or
            # three uops on Intel), while the select of the value against zero
            # is one AND.  With FMA the 0.0 / 1.0 ``unit`` of a threshold
            # (one AND) serves both of its sums, and the adds move to the
            # multiply units: the block took 0.93-0.97x the time of
            # AND-then-add on an AMD EPYC, Zen 3 (asv CellBlockOrders).
            if unit is not None:
                return builder.call(fmuladd, [unit, value, total])
            if mask_then_add:
                return builder.fadd(total, builder.select(past, value, zero_f))
            return builder.select(past, builder.fadd(total, value), total)

        # fmuladd, not fma: fused where the CPU has FMA, a multiply and an add
        # otherwise, where llvm.fma would call libm's fmaf per lane: a frame's
        # cells took 74-78 ms against 6.6 with glibc's software fmaf, and the
        # block 1.6x as long even where glibc runs fmaf on the FMA unit
        # (baseline x86-64 target, AMD EPYC Zen 3).  Both are exact below.
        fmuladd = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(floats_t, [floats_t] * 3),
            f"llvm.fmuladd.v{lanes}f32")
        fabs = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(floats_t, [floats_t]), f"llvm.fabs.v{lanes}f32")
        zero64, one = ir.Constant(i64, 0), ir.Constant(i64, 1)
        last_row = builder.sub(height, one)
        zero_i = splat(0)
        zero_f = splat(0.0, floats_t)
        c_off = ir.Constant(i64, channels)
        undef_b = ir.Constant(bytes_t, ir.Undefined)
        # Accumulators: the magnitudes of acute (gx * gy >= 0) and of obtuse
        # pixels, each over all pixels and over those past each threshold.
        middle = len(thresholds)
        sums = [[] for _ in range(2 * (middle + 1))]

        def row_start(r):
            """Flat offset of the group in image row y0 + r, and the step to
            the rows above and below (0 on the image's first and last rows)."""
            y = builder.add(y0, r)
            interior = builder.and_(builder.icmp_signed(">", y, zero64),
                                    builder.icmp_signed("<", y, last_row))
            return (builder.add(builder.mul(y, row_bytes), x0),
                    builder.select(interior, row_bytes, zero64))

        def gradients(piece, start, step):
            """``|gx|``, ``|gy|`` and the magnitude of acute and of obtuse
            elements (0 for the others) of one piece in one row."""
            head = first and piece == 0
            tail = last and piece == pieces - 1
            base = builder.add(start, ir.Constant(i64, piece * lanes))
            up = builder.sub(base, step)
            down = builder.add(base, step)
            here = load(base) if head or tail else None
            if head:
                left = builder.shuffle_vector(here, undef_b, ir.Constant(
                    mask_t(lanes), [0] * channels + list(range(lanes - channels))))
            else:
                left = load(builder.sub(base, c_off))
            if tail:
                right = builder.shuffle_vector(here, undef_b, ir.Constant(
                    mask_t(lanes), list(range(channels, lanes)) + [lanes - 1] * channels))
            else:
                right = load(builder.add(base, c_off))
            gx = builder.sub(widen(right), widen(left))
            if head or tail:
                keep = [not ((head and j < channels) or (tail and j >= lanes - channels))
                        for j in range(lanes)]
                gx = builder.select(ir.Constant(ir.VectorType(ir.IntType(1), lanes),
                                                [int(k) for k in keep]), gx, zero_i)
            gy = builder.sub(widen(load(down)), widen(load(up)))
            fx = builder.sitofp(gx, floats_t)
            fy = builder.sitofp(gy, floats_t)
            # Exact: gx * gx + gy * gy < 2**24.
            magnitude = builder.call(sqrt, [builder.call(fmuladd, [fx, fx, builder.fmul(fy, fy)])])
            # gx * gy is exact; a zero product (gx = 0 or gy = 0) counts as
            # not obtuse, which changes nothing for gx = 0: k is the middle bin.
            obtuse = builder.fcmp_ordered("<", builder.fmul(fx, fy), zero_f)
            return (builder.call(fabs, [fx]), builder.call(fabs, [fy]),
                    builder.select(obtuse, zero_f, magnitude),
                    builder.select(obtuse, magnitude, zero_f))

        def accumulate(phis, ax, ay, acute_mag, obtuse_mag):
            # The threshold conditions are nested (monotone in k), so summing
            # each side's magnitudes past every threshold gives the bins as
            # differences later: two masked adds per threshold instead of a
            # bin index and a compare and masked add per bin.
            acute = [builder.fadd(phis[0], acute_mag)]
            obtuse_sums = [builder.fadd(phis[middle + 1], obtuse_mag)]
            for count, t in enumerate(thresholds, 1):
                past = builder.fcmp_ordered(">=", ay, builder.fmul(ax, splat(t, floats_t)))
                unit = (builder.select(past, splat(1.0, floats_t), zero_f) if fused_add
                        else None)
                acute.append(masked_add(past, phis[count], acute_mag, unit))
                obtuse_sums.append(masked_add(past, phis[middle + 1 + count], obtuse_mag, unit))
            return acute + obtuse_sums

        def row_loop(name, body, phi_count=0, launder=False):
            """``body(r, phis)`` for r = 0 .. ppc_y - 1; returns its last values."""
            before = builder.block
            loop = builder.append_basic_block(name)
            after = builder.append_basic_block(f"{name}_done")
            builder.branch(loop)
            builder.position_at_end(loop)
            r = builder.phi(i64)
            r.add_incoming(zero64, before)
            phis = []
            for _ in range(phi_count):
                phi = builder.phi(floats_t)
                phi.add_incoming(zero_f, before)
                phis.append(phi)
            values = body(r, phis)
            r_next = builder.add(r, one)
            r.add_incoming(r_next, builder.block)
            for phi, value in zip(phis, values):
                phi.add_incoming(value, builder.block)
            bound = ir.Constant(i64, ppc_y)
            # ``launder``: hide the constant trip count behind an empty asm,
            # so that LLVM keeps the loop.  Unrolled, the two-pass block's
            # eight-row sum loops became one long block that reloads its
            # thresholds and took 5.0 ms a frame against 4.2 (AMD EPYC, AVX2).
            if launder:
                bound = builder.asm(ir.FunctionType(i64, [i64]), "", "=r,0", [bound],
                                    side_effect=False)
            builder.cbranch(builder.icmp_signed("<", r_next, bound), loop, after)
            builder.position_at_end(after)
            return values

        if two_pass:
            # First every piece's gradients over the cell row's image rows,
            # into a stack buffer (6 KB, in L1), then each piece's sums from
            # it: the same operations on the same values, in the same order
            # per lane.  In one pass the sums wait on the loads, conversions
            # and square root of each row, and those waiting operations fill
            # the core's floating-point scheduler (Zen 3: 64 entries) before
            # the next rows' loads can start.
            kinds = 4
            stash = cgutils.alloca_once(builder, ir.ArrayType(floats_t, pieces * ppc_y * kinds))
            # The aligned loads and stores below rely on it.
            stash.align = 4 * lanes

            def slot(piece, r, kind):
                index = builder.add(builder.mul(r, ir.Constant(i64, kinds)),
                                    ir.Constant(i64, piece * ppc_y * kinds + kind))
                return builder.gep(stash, [zero64, index], inbounds=True)

            def gradient_row(r, _):
                start, step = row_start(r)
                for piece in range(pieces):
                    for kind, value in enumerate(gradients(piece, start, step)):
                        builder.store(value, slot(piece, r, kind), align=4 * lanes)
                return []

            row_loop("gradients", gradient_row)
            for piece in range(pieces):
                acc = row_loop(f"sums{piece}", lambda r, phis, piece=piece: accumulate(
                    phis, *[builder.load(slot(piece, r, kind), align=4 * lanes)
                            for kind in range(kinds)]), len(sums), launder=True)
                for total, value in zip(sums, acc):
                    total.append(value)
        else:
            for piece in range(pieces):
                acc = row_loop(f"piece{piece}", lambda r, phis, piece=piece: accumulate(
                    phis, *gradients(piece, *row_start(r))), len(sums))
                for total, value in zip(sums, acc):
                    total.append(value)

        # Per lane, bin k < middle holds the acute pixels past threshold k but
        # not k + 1, bin nbins - 1 - k the obtuse ones, the middle bin both
        # sides past the last threshold.  Float sums are monotone in their
        # terms, so these differences are never negative, and exactly 0 for
        # empty bins.
        middle_bin = [builder.fadd(a, o) for a, o in zip(sums[middle], sums[2 * middle + 1])]
        bins = [None] * nbins
        for k in range(middle):
            bins[k] = [builder.fsub(a, b) for a, b in zip(sums[k], sums[k + 1])]
            bins[nbins - 1 - k] = [builder.fsub(a, b) for a, b in
                                   zip(sums[middle + 1 + k], sums[middle + 2 + k])]
        bins[middle] = middle_bin
        vectors = [piece for pieces_of_bin in bins for piece in pieces_of_bin]
        # Add each (bin, cell, channel)'s pixels: a planned tree of two
        # shuffles and an add per output vector, each halving the pixels.
        for level in plan.levels:
            following = []
            for left, right in level:
                operands = []
                for (first_source, second_source), mask in (left, right):
                    a = vectors[first_source]
                    b = vectors[second_source] if second_source is not None else a
                    operands.append(builder.shuffle_vector(a, b, ir.Constant(mask_t(lanes), mask)))
                following.append(builder.fadd(*operands))
            vectors = following
        # The cell mean: 1 / (ppc_y * ppc_x) is a power of two, so scaling
        # here rounds exactly as scaling the stored sums would.
        mean = splat(1.0 / (ppc_y * ppc_x), floats_t)
        for v, vector in enumerate(vectors):
            store_vector(builder, builder.fmul(vector, mean), scratch,
                         ir.Constant(i64, v * lanes), align=4)
        return context.get_dummy_value()

    def block(typingctx, flat, height, row_bytes, y0, x0, scratch):
        return types.void(flat, height, row_bytes, y0, x0, scratch), codegen

    block.__name__ = block.__qualname__ = (
        f"_group_block_c{channels}_{'f' if first else ''}{'l' if last else ''}")
    return intrinsic(block)


_block3 = _group_block(3, 8, 8, 9, False, False)
_block3_f = _group_block(3, 8, 8, 9, True, False)
_block3_l = _group_block(3, 8, 8, 9, False, True)
_block3_fl = _group_block(3, 8, 8, 9, True, True)
_block1 = _group_block(1, 8, 8, 9, False, False)
_block1_f = _group_block(1, 8, 8, 9, True, False)
_block1_l = _group_block(1, 8, 8, 9, False, True)
_block1_fl = _group_block(1, 8, 8, 9, True, True)
_SLOTS3 = _reduction_plan(_LANES, 3, 8, 9).index
_SLOTS1 = _reduction_plan(_LANES, 1, 8, 9).index
_SCRATCH3 = _reduction_plan(_LANES, 3, 8, 9).size
_SCRATCH1 = _reduction_plan(_LANES, 1, 8, 9).size


@njit(cache=True, nogil=True, **CALLED_FROM_KERNELS_ONLY)
def _scalar_cells(flat, height, row_bytes, channels, y0, ppc_y, ppc_x, cx0, cx1, nbins, bin_lut,
                  acc):
    """Gradient-magnitude sums of cells cx0 .. cx1 - 1 of one cell row, one
    element at a time: acc[((cx - cx0) * channels + c) * (nbins + 1) + bin]."""
    acc[:] = 0.0
    c64 = uint64(channels)
    rb = uint64(row_bytes)
    start = uint64(cx0 * ppc_x) * c64
    stop = uint64(cx1 * ppc_x) * c64
    for y in range(y0, y0 + ppc_y):
        interior = y > 0 and y < height - 1
        mid = uint64(y) * rb
        up = mid - rb if interior else mid
        down = mid + rb if interior else mid
        for j in range(start, stop):
            gy = np.int32(flat[down + j]) - np.int32(flat[up + j])
            gx = np.int32(0)
            if j >= c64 and j + c64 < rb:
                gx = np.int32(flat[mid + j + c64]) - np.int32(flat[mid + j - c64])
            index = (gy + 255) * _GRAD_SPAN + (gx + 255)
            e = j - start
            slot = ((e // c64 // uint64(ppc_x)) * c64 + e % c64) * uint64(nbins + 1)
            acc[slot + uint64(bin_lut[uint64(index)])] += np.sqrt(np.float32(gx * gx + gy * gy))


@njit(cache=True, nogil=True, inline="always")
def _three_channel_block(head, tail, flat, height, row_bytes, y0, x0, scratch):
    """The group block of a three-channel row, by where the group lies in it."""
    if head and tail:
        _block3_fl(flat, height, row_bytes, y0, x0, scratch)
    elif head:
        _block3_f(flat, height, row_bytes, y0, x0, scratch)
    elif tail:
        _block3_l(flat, height, row_bytes, y0, x0, scratch)
    else:
        _block3(flat, height, row_bytes, y0, x0, scratch)


@njit(cache=True, nogil=True, inline="always")
def _one_channel_block(head, tail, flat, height, row_bytes, y0, x0, scratch):
    """The group block of a one-channel row, by where the group lies in it."""
    if head and tail:
        _block1_fl(flat, height, row_bytes, y0, x0, scratch)
    elif head:
        _block1_f(flat, height, row_bytes, y0, x0, scratch)
    elif tail:
        _block1_l(flat, height, row_bytes, y0, x0, scratch)
    else:
        _block1(flat, height, row_bytes, y0, x0, scratch)


@njit(cache=True, nogil=True)
def _cell_rows_u8_fast(image, first, stop, bin_lut, ncx, layout, out, channels):
    """Cell rows ``first`` .. ``stop - 1`` of the default configuration
    (nbins 9, 8x8 cells, 1 or 3 channels), the cells of whole groups of
    _GROUP_CELLS (the last one of an odd ``ncx`` is :func:`_cell_rows_u8_tail`'s);
    same results as :func:`_cell_rows_u8` up to float32 summation order.

    ``channels`` None: the image has 3, and only their blocks are compiled
    (Numba drops the branches of a None argument before typing: the
    detector's colour images compile no one-channel blocks, about 0.25 s of
    the family's first compile).  Otherwise the image's channel count, 1 or
    3, chosen at run time.
    """
    height, width = image.shape[0], image.shape[1]
    n_channels = 3 if channels is None else channels
    flat = flat_view(image)
    nbins = _FAST_NBINS
    ppc_y, ppc_x = _FAST_PPC
    row_bytes = width * n_channels
    group = _GROUP_CELLS * ppc_x * n_channels
    groups = ncx // _GROUP_CELLS
    outputs = _GROUP_CELLS * n_channels
    # Where the block stores each (bin, cell, channel) mean.
    slot = _SLOTS3 if n_channels == 3 else _SLOTS1
    scratch = empty(_SCRATCH3 if n_channels == 3 else _SCRATCH1, dtype=np.float32)
    c64 = uint64(n_channels)
    phase_step, per_phase = layout[4], layout[5]
    position_stride, channel_stride, bin_stride = layout[1], layout[2], layout[3]
    for cell_row in range(first, stop):
        y0 = cell_row * ppc_y
        row_base = uint64(cell_row) * layout[0]
        # Cell column cx sits at position (cx % step) * K + cx // step: kept
        # as two counters, not divided per cell.
        phase = uint64(0)
        column = uint64(0)
        for g in range(groups):
            x0 = g * group
            head = x0 == 0
            tail = x0 + group == row_bytes
            if channels is None or n_channels == 3:
                _three_channel_block(head, tail, flat, height, row_bytes, y0, x0, scratch)
            else:
                _one_channel_block(head, tail, flat, height, row_bytes, y0, x0, scratch)
            for cell in range(uint64(_GROUP_CELLS)):
                position = phase * per_phase + column
                phase += uint64(1)
                if phase == phase_step:
                    phase = uint64(0)
                    column += uint64(1)
                for c in range(c64):
                    dest = row_base + position * position_stride + c * channel_stride
                    src = cell * c64 + c
                    for b in range(uint64(nbins)):
                        out[dest + b * bin_stride] = scratch[slot[b * uint64(outputs) + src]]


@njit(cache=True, nogil=True)
def _cell_rows_u8_tail(image, first, stop, bin_lut, ncx, layout, out):
    """The cells of rows ``first`` .. ``stop - 1`` past :func:`_cell_rows_u8_fast`'s
    whole groups, one element at a time.  A kernel of its own: compiled only for
    images with an odd number of cell columns, which the default search's
    scales at 960, 1280 and 1920 pixels do not have."""
    height, width, channels = image.shape
    flat = flat_view(image)
    nbins = _FAST_NBINS
    ppc_y, ppc_x = _FAST_PPC
    cx0 = ncx // _GROUP_CELLS * _GROUP_CELLS
    rest = ncx - cx0
    acc = empty(max(rest, 1) * channels * (nbins + 1), dtype=np.float32)
    scale = np.float32(1.0 / (ppc_y * ppc_x))
    c64 = uint64(channels)
    if rest == 0:
        return
    for cell_row in range(first, stop):
        row_base = uint64(cell_row) * layout[0]
        _scalar_cells(flat, height, width * channels, channels, cell_row * ppc_y, ppc_y, ppc_x,
                      cx0, ncx, nbins, bin_lut, acc)
        for k in range(uint64(rest)):
            cx = uint64(cx0) + k
            position = (cx % layout[4]) * layout[5] + cx // layout[4]
            for c in range(c64):
                dest = row_base + position * layout[1] + c * layout[2]
                base = (k * c64 + c) * uint64(nbins + 1)
                for b in range(uint64(nbins)):
                    out[dest + b * layout[3]] = acc[base + b] * scale


@njit(cache=True, parallel=True)
def _cell_histograms_u8_fast_parallel(image, bin_lut, bands, rows, ncx, layout, out):
    # One contiguous band of cell rows per thread, as in the table path.
    for band in prange(bands):
        first, stop = band * rows // bands, (band + 1) * rows // bands
        _cell_rows_u8_fast(image, first, stop, bin_lut, ncx, layout, out, image.shape[2])
        _cell_rows_u8_tail(image, first, stop, bin_lut, ncx, layout, out)
