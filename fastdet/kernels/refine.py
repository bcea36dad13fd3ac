"""Heat statistics of blob boxes: the features of the box refinement.

:func:`fastdet.detector.refine.heat_features` defines the features (its
docstring says what each one measures); this kernel computes them for all
of a frame's boxes in one call.  Per box it makes one pass over the heat
inside the box for the column and row sums and peaks of the mass
``max(heat - threshold, 0)``; the extent of the mass at or above
``level * peak`` is where the column and row peaks reach it, and the
centroid and the spread come from the column and row sums.  Done in NumPy, a box cost some forty array
calls (about 0.15 ms); here it is a few microseconds.

All sums are float64, as in NumPy; they add in raster order, so a feature
may differ from a NumPy sum's pairwise order in the last bits.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .alloc import empty, zeros
from .inner import CALLED_FROM_KERNELS_ONLY
from .prefetch import LINE_BYTES, prefetch_byte

__all__ = ["box_heat_features", "snap_box_sides"]


@njit(cache=True, nogil=True)
def box_heat_features(heat, origin_x, origin_y, boxes, threshold, frame_width, frame_height,
                      levels, out):
    """Write the refinement features of each box into ``out``.

    Parameters
    ----------
    heat : ndarray of float32 or float64, shape (h, w)
        Heat over a region of the frame whose top-left pixel is
        ``(origin_x, origin_y)``.
    origin_x, origin_y : int
    boxes : ndarray of int64, shape (N, 4)
        ``x1, y1, x2, y2`` in frame pixels, ``x2``/``y2`` exclusive.
    threshold : float
        The heat threshold the blobs were cut at.
    frame_width, frame_height : int
    levels : ndarray of float64, shape (L,)
        Fractions of the peak mass whose extents are features (above 1
        taken as 1).
    out : ndarray of float64, shape (N, 1 + 4 * L + 6)
        Filled with the features of
        :func:`fastdet.detector.refine.heat_features`, in its order.
    """
    n_levels = levels.shape[0]
    height_px, width_px = heat.shape
    columns = empty(width_px, np.float64)
    rows = empty(height_px, np.float64)
    column_peaks = empty(width_px, np.float64)
    row_peaks = empty(height_px, np.float64)
    last = out.shape[1]
    for row in range(boxes.shape[0]):
        x1, y1, x2, y2 = boxes[row, 0], boxes[row, 1], boxes[row, 2], boxes[row, 3]
        out[row, 0] = 1.0
        out[row, last - 2] = math.log(max(y2 - y1, 1) / frame_height)
        out[row, last - 1] = abs((x1 + x2) / 2 - frame_width / 2) / frame_height
        flip = x1 + x2 < frame_width
        width = max(x2 - x1, 1)
        height = max(y2 - y1, 1)
        cx = (x1 + x2) / 2
        cy = (y1 + y2) / 2
        a1, b1 = max(x1 - origin_x, 0), max(y1 - origin_y, 0)
        a2, b2 = min(x2 - origin_x, width_px), min(y2 - origin_y, height_px)
        total = 0.0
        peak = 0.0
        if a2 > a1 and b2 > b1:
            for a in range(a1, a2):
                columns[a] = 0.0
                column_peaks[a] = 0.0
            for b in range(b1, b2):
                line = 0.0
                line_peak = 0.0
                for a in range(a1, a2):
                    mass = max(np.float64(heat[b, a]) - threshold, 0.0)
                    line += mass
                    line_peak = max(line_peak, mass)
                    columns[a] += mass
                    column_peaks[a] = max(column_peaks[a], mass)
                rows[b] = line
                row_peaks[b] = line_peak
                total += line
                peak = max(peak, line_peak)
        if not total > 0.0:
            # No heat inside (a box moved off its blob): the features of a
            # flat blob filling its box.
            for k in range(n_levels):
                out[row, 1 + 4 * k] = -0.5
                out[row, 2 + 4 * k] = -0.5
                out[row, 3 + 4 * k] = 0.5
                out[row, 4 + 4 * k] = 0.5
            col = 1 + 4 * n_levels
            out[row, col] = 0.0
            out[row, col + 1] = 0.0
            out[row, col + 2] = 0.29
            out[row, col + 3] = 0.29
            continue
        # Pixel centres relative to the box centre, in box widths and heights.
        x_shift = origin_x + 0.5 - cx
        y_shift = origin_y + 0.5 - cy
        col = 1
        for k in range(n_levels):
            # A column (row) holds mass at or above the bound exactly when
            # its peak does: the extents come from the peaks alone.  The
            # bound is at most the peak, so the scans stop at the latest on
            # the peak's column and row.
            bound = min(levels[k], 1.0) * peak
            left, right = a1, a2 - 1
            while column_peaks[left] < bound:
                left += 1
            while column_peaks[right] < bound:
                right -= 1
            top, bottom = b1, b2 - 1
            while row_peaks[top] < bound:
                top += 1
            while row_peaks[bottom] < bound:
                bottom -= 1
            x_left = (left + x_shift) / width - 0.5 / width
            x_right = (right + x_shift) / width + 0.5 / width
            if flip:
                x_left, x_right = -x_right, -x_left
            out[row, col] = x_left
            out[row, col + 1] = (top + y_shift) / height - 0.5 / height
            out[row, col + 2] = x_right
            out[row, col + 3] = (bottom + y_shift) / height + 0.5 / height
            col += 4
        mx = 0.0
        for a in range(a1, a2):
            mx += columns[a] * ((a + x_shift) / width)
        mx /= total
        my = 0.0
        for b in range(b1, b2):
            my += rows[b] * ((b + y_shift) / height)
        my /= total
        # d * d, not d ** 2: the same float64, without compiling Numba's int_power.
        spread_x = 0.0
        for a in range(a1, a2):
            offset = (a + x_shift) / width - mx
            spread_x += columns[a] * (offset * offset)
        spread_y = 0.0
        for b in range(b1, b2):
            offset = (b + y_shift) / height - my
            spread_y += rows[b] * (offset * offset)
        out[row, col] = -mx if flip else mx
        out[row, col + 1] = my
        out[row, col + 2] = math.sqrt(spread_x / total)
        out[row, col + 3] = math.sqrt(spread_y / total)


@njit(cache=True, nogil=True)
def refined_edges(boxes, features, weights, frame_widths, out):
    """Place each box's edges by the linear refinement model.

    Parameters
    ----------
    boxes : ndarray of int64, shape (N, 4)
    features : ndarray of float64, shape (N, F)
        :func:`box_heat_features` of the boxes.
    weights : ndarray of float64, shape (4, F)
        Rows for x1, y1, x2, y2 of the mirrored box (left of the middle).
    frame_widths : ndarray of float64, shape (N,)
        Width of each box's frame; a box whose ``x1 + x2`` is below it is
        mirrored.
    out : ndarray of float64, shape (N, 4)
        The refined boxes, unrounded; an edge pair the model crosses is put
        back in order.
    """
    for row in range(boxes.shape[0]):
        x1, y1, x2, y2 = boxes[row, 0], boxes[row, 1], boxes[row, 2], boxes[row, 3]
        offsets = zeros(4)
        for edge in range(4):
            for k in range(features.shape[1]):
                offsets[edge] += features[row, k] * weights[edge, k]
        left, top, right, bottom = offsets[0], offsets[1], offsets[2], offsets[3]
        if x1 + x2 < frame_widths[row]:
            left, right = -right, -left
        width = x2 - x1
        height = y2 - y1
        cx = (x1 + x2) / 2
        cy = (y1 + y2) / 2
        ex1, ey1 = cx + left * width, cy + top * height
        ex2, ey2 = cx + right * width, cy + bottom * height
        out[row, 0] = min(ex1, ex2)
        out[row, 1] = min(ey1, ey2)
        out[row, 2] = max(ex1, ex2)
        out[row, 3] = max(ey1, ey2)


@njit(cache=True, nogil=True, **CALLED_FROM_KERNELS_ONLY)
def _strongest_column(frame, centre, reach, first_row, stop_row, first_column, stop_column,
                      smoothed, strength):
    """The column within ``reach`` of ``centre`` (and inside ``first_column`` ..
    ``stop_column - 1``) of the strongest vertical edges; the first of equals;
    -1 when none lies inside or none has an edge.

    ``|Sobel x|`` is ``|V[c + 1] - V[c - 1]|`` with ``V`` the column-smoothed
    intensity ``I[r - 1] + 2 I[r] + I[r + 1]``: each row's ``V`` is made
    once (into ``smoothed``) and read twice, row by row along the frame's
    memory.
    """
    low = max(centre - reach, first_column)
    high = min(centre + reach, stop_column - 1)
    count = high - low + 1
    if count <= 0:
        return -1
    for k in range(count):
        strength[k] = 0
    # Ask for all the strip's lines at once (see fastdet.kernels.prefetch):
    # the frame's rows come from memory, one short run each, and read one
    # after the other each would wait for its own miss.
    row_bytes, pixel_bytes = np.int64(frame.strides[0]), np.int64(frame.strides[1])
    start = np.int64(low - 1) * pixel_bytes
    for row in range(first_row - 1, stop_row + 1):
        for offset in range(start, start + (count + 2) * pixel_bytes + LINE_BYTES - 1,
                            LINE_BYTES):
            prefetch_byte(frame, row * row_bytes + offset)
    for row in range(first_row, stop_row):
        for k in range(count + 2):
            column = low - 1 + k
            total = np.int32(0)
            for c in range(3):
                total += (np.int32(frame[row - 1, column, c]) + 2 * np.int32(frame[row, column, c])
                          + np.int32(frame[row + 1, column, c]))
            smoothed[k] = total
        for k in range(count):
            strength[k] += abs(smoothed[k + 2] - smoothed[k])
    best, best_column = np.int64(0), -1
    for k in range(count):
        if strength[k] > best:
            best, best_column = strength[k], low + k
    return best_column


@njit(cache=True, nogil=True)
def snap_box_sides(frame, boxes, fraction, limits, out):
    """Move each box's left and right edges to the strongest vertical image edge nearby.

    A car's sides are the strongest vertical edges about its box (its body
    against the road or the next lane); the heat places them only as finely
    as the window grid.  For each edge, the columns within ``fraction`` of
    the box width of it (at least one) are scored by the sum of ``|Sobel
    x|`` of the intensity ``B + G + R`` over the middle half of the box's
    rows, and the edge moves to the best one (the first of equals): the left
    edge onto it, the right edge (exclusive) just past it.  A box whose
    edges would cross, or that has no such rows, is left as it is, and so
    is a side with no gradient within reach (flat image).

    Parameters
    ----------
    frame : ndarray of uint8, shape (H, W, 3)
    boxes : ndarray of int64, shape (N, 4)
        ``x1, y1, x2, y2`` (exclusive ends) in frame pixels.
    fraction : float
    limits : ndarray of int64, shape (4,)
        ``x0, y0, x1, y1``: the only part of the frame read (a caller may
        have converted only the rows the detector searches); the Sobel
        stencil stays inside it.
    out : ndarray of int64, shape (N, 4)
    """
    # Per side at most 2 * reach + 1 candidates, reach at most half a box.
    smoothed = empty(frame.shape[1] + 3, dtype=np.int32)
    strength = empty(frame.shape[1] + 1, dtype=np.int64)
    first_column = max(limits[0], 0) + 1
    stop_column = min(limits[2], frame.shape[1]) - 1
    first_limit = max(limits[1], 0) + 1
    stop_limit = min(limits[3], frame.shape[0]) - 1
    for i in range(boxes.shape[0]):
        x1, y1, x2, y2 = boxes[i, 0], boxes[i, 1], boxes[i, 2], boxes[i, 3]
        for k in range(4):
            out[i, k] = boxes[i, k]
        width, height = x2 - x1, y2 - y1
        first_row = max(y1 + height // 4, first_limit)
        stop_row = min(y2 - height // 4, stop_limit)
        if width < 2 or first_row >= stop_row:
            continue
        reach = max(int(fraction * width), 1)
        left = _strongest_column(frame, x1, reach, first_row, stop_row, first_column,
                                 stop_column, smoothed, strength)
        right = _strongest_column(frame, x2, reach, first_row, stop_row, first_column,
                                  stop_column, smoothed, strength)
        # Each side on its own: a side without an edge in reach stays.
        new_x1 = left if left >= 0 else x1
        new_x2 = right + 1 if right >= 0 else x2
        if new_x1 < new_x2:
            out[i, 0] = new_x1
            out[i, 2] = new_x2

