"""Heat-map accumulation of weighted boxes.

A detector emits many overlapping windows per vehicle; summing their scores
into a per-pixel "heat" map and thresholding it merges them into one blob.

Algorithm
---------
Painting every box pixel by pixel costs O(sum of box areas), which explodes
with many large, heavily overlapping windows.  Instead each box
``[x1, y1, x2, y2)`` with weight ``w`` writes four entries into a 2-D
difference array ``D``::

    D[y1, x1] += w    D[y1, x2] -= w
    D[y2, x1] -= w    D[y2, x2] += w

The inclusive 2-D prefix sum ``S[y, x] = sum(D[:y + 1, :x + 1])`` is then
exactly the summed weight of all boxes covering pixel ``(y, x)``.

``D`` is nonzero only on the rows and columns where some box starts or ends,
so it is kept compressed: the sorted distinct box edges ``X`` (plus 0) and
``Y`` (plus 0) cut the map into a grid of cells ``[Y[i], Y[i+1]) x [X[j],
X[j+1])`` on which the heat is constant, and ``D`` is a ``(len(Y) + 1,
len(X) + 1)`` array over edge indices.  One raster pass over the cells
computes the prefix sum (a running sum along the row and a running sum per
column), and the map is filled by writing each cell's value over its pixels
(whole pixel rows of a cell row are plain row copies).  Total work is
O(N + H + W + cells) plus writing the H * W output.

This is the same arithmetic as the full-resolution prefix sum: there, every
entry of ``D`` off the edge grid is an untouched +0.0, and adding +0.0 to a
running sum changes nothing (no sum here is ever -0.0: every accumulator
starts at +0.0 and IEEE addition gives -0.0 only for two -0.0 operands), so
each pixel's running sums see exactly the additions, in the same order, as
its cell's.  The output is therefore bit for bit that of the plain
difference-array method, whatever the weights.

Exactness
---------
``D`` and the running sums are float64.  Every float32 weight is an integer
multiple of the smallest weight's ulp, and float64 has 29 more mantissa bits
than float32, so as long as the weights span a moderate dynamic range (e.g.
``1e-3 .. 1e3`` with thousands of boxes) every partial sum is representable
and all additions are exact.  The result is therefore the exactly summed
weight rounded once to float32: pixels covered by no box are exactly ``0.0``
(no ``+w - w`` residue that would survive a ``heat > 0`` threshold), and the
output is bit-identical to a naive per-box float64 accumulation.
"""

from __future__ import annotations

import numba
import numpy as np

from .alloc import empty, zeros

__all__ = ["accumulate_heat", "accumulate_heat_into", "box_heat_region", "decay_heat",
           "heat_cells", "windows_above"]


@numba.njit(cache=True, nogil=True, inline="always")
def _clip(value, size):
    return min(max(np.int64(value), 0), size)


@numba.njit(cache=True, nogil=True, inline="always")
def _edge_starts(index, size):
    """Turn edge marks into cell numbers, in place; return the cell starts.

    ``index[v]`` is nonzero where a cell starts (``index[0]`` always is).
    Afterwards ``index[v]`` is the number of the cell starting at ``v`` for
    every marked ``v < size`` and ``index[size]`` is the cell count; the
    returned ``starts`` has ``count + 1`` entries ending with ``size``.
    """
    count = 0
    for v in range(size):
        if index[v] != 0:
            count += 1
    starts = empty(count + 1, dtype=np.int64)
    cell = 0
    for v in range(size):
        if index[v] != 0:
            starts[cell] = v
            index[v] = cell
            cell += 1
    starts[count] = size
    index[size] = count
    return starts


# Inlined in Numba's IR (as _paint): compiled with its caller instead of on its
# own and then optimised again there (the heat family compiles 0.2 s sooner).
@numba.njit(cache=True, nogil=True, inline="always")
def heat_cells(boxes, weights, x0, y0, height, width):
    """Heat of weighted boxes on the grid of cells their edges cut a map into.

    The heat map of ``accumulate_heat(boxes - [x0, y0, x0, y0], weights,
    height, width)`` is constant on each cell ``[row_starts[i],
    row_starts[i + 1]) x [col_starts[j], col_starts[j + 1])``; this returns
    those cells and their values without touching the pixels.

    Parameters
    ----------
    boxes : numpy.ndarray
        Integer array of shape ``(N, 4)``, rows ``[x1, y1, x2, y2]``
        (exclusive ends) in coordinates where the map starts at ``(x0, y0)``.
    weights : numpy.ndarray
        float32 array of shape ``(N,)``.
    x0, y0 : int
        Map origin in box coordinates.
    height, width : int
        Map shape; boxes are clipped to it.

    Returns
    -------
    row_starts : numpy.ndarray
        int64 array ``(R + 1,)``, increasing, from 0 to ``height`` (just
        ``[height]`` when ``height`` is 0).
    col_starts : numpy.ndarray
        int64 array ``(C + 1,)``, likewise for columns.
    cells : numpy.ndarray
        float32 array ``(R, C)``, the heat of each cell.

    Raises
    ------
    ValueError
        If ``boxes`` does not have 4 columns or ``weights`` does not have one
        entry per box.
    """
    n_boxes = boxes.shape[0]
    if boxes.shape[1] != 4:
        raise ValueError("boxes must have shape (N, 4)")
    if weights.shape[0] != n_boxes:
        raise ValueError("weights must have one entry per box")
    clipped = empty((n_boxes, 4), dtype=np.int64)
    col_index = zeros(width + 1, dtype=np.int32)
    row_index = zeros(height + 1, dtype=np.int32)
    col_index[0] = 1
    row_index[0] = 1
    for i in range(n_boxes):
        x1 = _clip(boxes[i, 0] - np.int64(x0), width)
        y1 = _clip(boxes[i, 1] - np.int64(y0), height)
        x2 = _clip(boxes[i, 2] - np.int64(x0), width)
        y2 = _clip(boxes[i, 3] - np.int64(y0), height)
        clipped[i, 0] = x1
        clipped[i, 1] = y1
        clipped[i, 2] = x2
        clipped[i, 3] = y2
        if x2 <= x1 or y2 <= y1:
            continue
        col_index[x1] = 1
        col_index[x2] = 1
        row_index[y1] = 1
        row_index[y2] = 1
    col_starts = _edge_starts(col_index, width)
    row_starts = _edge_starts(row_index, height)
    n_rows = row_starts.size - 1
    n_cols = col_starts.size - 1

    # The difference array over edge indices; index n_rows / n_cols stands
    # for the map's far edge, which no cell reaches.  Boxes are added in
    # input order, as the full-resolution method would.
    diff = zeros((n_rows + 1, n_cols + 1), dtype=np.float64)
    for i in range(n_boxes):
        x1, y1, x2, y2 = clipped[i, 0], clipped[i, 1], clipped[i, 2], clipped[i, 3]
        if x2 <= x1 or y2 <= y1:
            continue
        weight = np.float64(weights[i])
        c1, c2 = col_index[x1], col_index[x2]
        r1, r2 = row_index[y1], row_index[y2]
        diff[r1, c1] += weight
        diff[r1, c2] -= weight
        diff[r2, c1] -= weight
        diff[r2, c2] += weight

    cells = empty((n_rows, n_cols), dtype=np.float32)
    column_sum = zeros(n_cols, dtype=np.float64)
    for r in range(n_rows):
        row_sum = 0.0
        for c in range(n_cols):
            row_sum += diff[r, c]
            column_sum[c] += row_sum
            cells[r, c] = np.float32(column_sum[c])
    return row_starts, col_starts, cells


@numba.njit(cache=True, nogil=True, inline="always")
def _paint(heat, row_starts, col_starts, cells):
    """Write every cell's value over its pixels (``heat`` fully overwritten)."""
    width = heat.shape[1]
    for r in range(row_starts.size - 1):
        y = row_starts[r]
        for c in range(col_starts.size - 1):
            value = cells[r, c]
            for x in range(col_starts[c], col_starts[c + 1]):
                heat[y, x] = value
        for other in range(y + 1, row_starts[r + 1]):
            for x in range(width):
                heat[other, x] = heat[y, x]


@numba.njit(cache=True, nogil=True)
def accumulate_heat_into(heat, boxes, weights):
    """Add the weighted-box heat map into an existing heat map, in place.

    Equivalent to ``heat += accumulate_heat(boxes, weights, *heat.shape)``
    (float32 addition of the rounded box heat onto the existing content), but
    without allocating the intermediate map.

    Parameters
    ----------
    heat : numpy.ndarray
        float32 array of shape ``(height, width)``; modified in place.
    boxes : numpy.ndarray
        int32 array of shape ``(N, 4)``, rows ``[x1, y1, x2, y2]`` in pixels
        with ``x2`` and ``y2`` exclusive.  Boxes are clipped to the map;
        boxes that are empty after clipping contribute nothing.
    weights : numpy.ndarray
        float32 array of shape ``(N,)``, the value added to every pixel of
        the corresponding box.

    Returns
    -------
    None

    Raises
    ------
    ValueError
        If ``boxes`` does not have 4 columns or ``weights`` does not have one
        entry per box (checked because either would read out of bounds).

    Notes
    -----
    Work is O(N + height + width + cells) plus one add per pixel; see the
    module docstring for the exactness guarantee.
    """
    height, width = heat.shape
    row_starts, col_starts, cells = heat_cells(boxes, weights, 0, 0, height, width)
    if boxes.shape[0] == 0:
        return
    for r in range(row_starts.size - 1):
        for y in range(row_starts[r], row_starts[r + 1]):
            for c in range(col_starts.size - 1):
                value = cells[r, c]
                for x in range(col_starts[c], col_starts[c + 1]):
                    heat[y, x] += value


@numba.njit(cache=True, nogil=True)
def accumulate_heat(boxes, weights, height, width):
    """Sum box weights into a new per-pixel heat map.

    Parameters
    ----------
    boxes : numpy.ndarray
        int32 array of shape ``(N, 4)``, rows ``[x1, y1, x2, y2]`` in pixels
        with ``x2`` and ``y2`` exclusive.  Boxes are clipped to the map;
        boxes that are empty after clipping contribute nothing.  ``N`` may
        be 0.
    weights : numpy.ndarray
        float32 array of shape ``(N,)``, the value added to every pixel of
        the corresponding box.
    height, width : int
        Shape of the heat map.

    Returns
    -------
    numpy.ndarray
        float32 array of shape ``(height, width)`` where each pixel holds the
        summed weight of all boxes containing it (0 where none does).

    Raises
    ------
    ValueError
        If ``boxes`` does not have 4 columns or ``weights`` does not have one
        entry per box.

    See Also
    --------
    accumulate_heat_into : Same accumulation onto an existing map.
    heat_cells : The piecewise-constant heat without the pixels.

    Examples
    --------
    >>> boxes = np.array([[0, 0, 2, 2], [1, 1, 3, 2]], dtype=np.int32)
    >>> weights = np.array([1.0, 0.5], dtype=np.float32)
    >>> accumulate_heat(boxes, weights, 2, 3)
    array([[1. , 1. , 0. ],
           [1. , 1.5, 0.5]], dtype=float32)
    """
    row_starts, col_starts, cells = heat_cells(boxes, weights, 0, 0, height, width)
    heat = empty((height, width), dtype=np.float32)
    _paint(heat, row_starts, col_starts, cells)
    return heat


@numba.njit(cache=True, nogil=True)
def windows_above(scores, threshold, boxes, scale_index):
    """The windows whose score exceeds a threshold: their boxes, scores and scales.

    The same arrays as ``hit = np.flatnonzero(scores > threshold)`` and
    ``boxes[hit], scores[hit], scale_index[hit]``, in one call: right after
    a frame's search those five NumPy calls found their code and data out of
    cache and took 60-90 us a frame, the kernel 25 us (AMD EPYC Zen 4).

    Parameters
    ----------
    scores : numpy.ndarray
        float32 array ``(N,)``.
    threshold : numpy.float32
        Compared in float32, as NumPy compares a float32 array with a Python
        float.
    boxes : numpy.ndarray
        int32 array ``(N, 4)``.
    scale_index : numpy.ndarray
        int64 array ``(N,)``.

    Returns
    -------
    boxes, scores, scale_index : numpy.ndarray
        The rows of the windows above the threshold, in window order.
    """
    n_windows = scores.shape[0]
    if boxes.shape[0] != n_windows or boxes.shape[1] != 4 or scale_index.shape[0] != n_windows:
        raise ValueError("scores, boxes (N, 4) and scale_index must have one row per window")
    threshold = np.float32(threshold)
    count = 0
    for i in range(n_windows):
        if scores[i] > threshold:
            count += 1
    hit_boxes = empty((count, 4), dtype=np.int32)
    hit_scores = empty(count, dtype=np.float32)
    hit_scales = empty(count, dtype=np.int64)
    k = 0
    for i in range(n_windows):
        if scores[i] > threshold:
            for side in range(4):
                hit_boxes[k, side] = boxes[i, side]
            hit_scores[k] = scores[i]
            hit_scales[k] = scale_index[i]
            k += 1
    return hit_boxes, hit_scores, hit_scales


@numba.njit(cache=True, nogil=True)
def box_heat_region(boxes, weights, width, height):
    """Heat of weighted boxes over their bounding region within a frame.

    Parameters
    ----------
    boxes : numpy.ndarray
        Integer array of shape ``(N, 4)``, rows ``[x1, y1, x2, y2]`` in frame
        pixels, exclusive ends.
    weights : numpy.ndarray
        float32 array of shape ``(N,)``.
    width, height : int
        Frame size.

    Returns
    -------
    heat : numpy.ndarray
        float32 array of shape ``(y1 - y0, x1 - x0)``: ``accumulate_heat`` of
        the boxes shifted by ``-(x0, y0)``, where ``x0, y0`` are the smallest
        box starts and ``x1, y1`` the largest box ends, clipped to the frame;
        ``(0, 0)`` for no boxes.
    x0, y0 : int
        Origin of the region in the frame.

    Raises
    ------
    ValueError
        If the region is empty in a way that gives a negative shape (every
        box beyond the frame), or the arguments have the wrong shapes.
    """
    n_boxes = boxes.shape[0]
    if boxes.shape[1] != 4:
        raise ValueError("boxes must have shape (N, 4)")
    if n_boxes == 0:
        return zeros((0, 0), dtype=np.float32), 0, 0
    x0, y0 = np.int64(boxes[0, 0]), np.int64(boxes[0, 1])
    x1, y1 = np.int64(boxes[0, 2]), np.int64(boxes[0, 3])
    for i in range(1, n_boxes):
        x0 = min(x0, np.int64(boxes[i, 0]))
        y0 = min(y0, np.int64(boxes[i, 1]))
        x1 = max(x1, np.int64(boxes[i, 2]))
        y1 = max(y1, np.int64(boxes[i, 3]))
    x0, y0 = max(x0, 0), max(y0, 0)
    x1, y1 = min(x1, np.int64(width)), min(y1, np.int64(height))
    if x1 < x0 or y1 < y0:
        raise ValueError("negative dimensions: every box lies beyond the frame")
    row_starts, col_starts, cells = heat_cells(boxes, weights, x0, y0, y1 - y0, x1 - x0)
    heat = empty((y1 - y0, x1 - x0), dtype=np.float32)
    _paint(heat, row_starts, col_starts, cells)
    return heat, x0, y0


@numba.njit(cache=True, nogil=True)
def decay_heat(state, heat, x0, y0, keep, weight):
    """One step of exponential heat smoothing, in place, in one pass over ``state``.

    ``state *= keep``, then ``state[y0:y0 + h, x0:x0 + w] += weight * heat``
    (``heat`` of shape ``(h, w)``), rounded as NumPy rounds those two
    statements in float32: the product, then the sum.  (In NumPy the decay
    is a pass over the whole map and the region's product a temporary of
    its own: 0.33 ms on the 1280x194 search band of a 1280x720 frame with a
    900x150 region; the kernel cut the pipeline's temporal steps from 0.49
    to 0.37 ms per test-video frame.)

    Parameters
    ----------
    state : numpy.ndarray
        float32 array ``(H, W)``, the smoothed map; updated in place.
    heat : numpy.ndarray
        float32 array ``(h, w)``, the current heat over a region of the map.
    x0, y0 : int
        Where the region starts in the map; it must lie inside the map.
    keep, weight : numpy.float32
        ``1 - alpha`` and ``alpha``.
    """
    height, width = state.shape
    rows, columns = heat.shape
    if x0 < 0 or y0 < 0 or x0 + columns > width or y0 + rows > height:
        raise ValueError("the heat region must lie inside the map")
    keep = np.float32(keep)
    weight = np.float32(weight)
    for y in range(height):
        line = state[y]
        for x in range(width):
            line[x] = line[x] * keep
        if y0 <= y < y0 + rows:
            source = heat[y - y0]
            for x in range(columns):
                line[x0 + x] = line[x0 + x] + weight * source[x]
