"""Heat-map accumulation of weighted boxes.

A detector emits many overlapping windows per vehicle; summing their scores
into a per-pixel "heat" map and thresholding it merges them into one blob.

Algorithm
---------
Painting every box pixel by pixel costs O(sum of box areas), which explodes
with many large, heavily overlapping windows.  Instead each box
``[x1, y1, x2, y2)`` with weight ``w`` writes four entries into a 2-D
difference array ``D`` of shape ``(H + 1, W + 1)``::

    D[y1, x1] += w    D[y1, x2] -= w
    D[y2, x1] -= w    D[y2, x2] += w

The inclusive 2-D prefix sum ``S[y, x] = sum(D[:y + 1, :x + 1])`` is then
exactly the summed weight of all boxes covering pixel ``(y, x)``.  A single
raster pass computes it by keeping a running sum along the current row and a
running sum per column, so the total work is O(N + H * W) regardless of box
sizes or overlap.

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

__all__ = ["accumulate_heat", "accumulate_heat_into"]


@numba.njit(cache=True)
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
    Work is O(N + height * width) and extra memory O(height * width)
    float64; see the module docstring for the exactness guarantee.
    """
    n_boxes = boxes.shape[0]
    if boxes.shape[1] != 4:
        raise ValueError("boxes must have shape (N, 4)")
    if weights.shape[0] != n_boxes:
        raise ValueError("weights must have one entry per box")
    height, width = heat.shape
    if n_boxes == 0 or height == 0 or width == 0:
        return

    # One extra row/column so corners at x2 == width / y2 == height need no
    # special case; those entries never reach a pixel inside the map.
    diff = np.zeros((height + 1, width + 1), dtype=np.float64)
    for i in range(n_boxes):
        x1 = min(max(np.int64(boxes[i, 0]), 0), width)
        y1 = min(max(np.int64(boxes[i, 1]), 0), height)
        x2 = min(max(np.int64(boxes[i, 2]), 0), width)
        y2 = min(max(np.int64(boxes[i, 3]), 0), height)
        if x2 <= x1 or y2 <= y1:
            continue
        weight = np.float64(weights[i])
        diff[y1, x1] += weight
        diff[y1, x2] -= weight
        diff[y2, x1] -= weight
        diff[y2, x2] += weight

    # column_sum[x] holds the prefix sum over all rows so far of the row-wise
    # prefix sums, i.e. the full 2-D prefix sum at (y, x); this fuses both
    # prefix-sum directions into one pass and touches `diff` exactly once.
    column_sum = np.zeros(width, dtype=np.float64)
    for y in range(height):
        row_sum = 0.0
        for x in range(width):
            row_sum += diff[y, x]
            column_sum[x] += row_sum
            heat[y, x] += np.float32(column_sum[x])


@numba.njit(cache=True)
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

    Examples
    --------
    >>> boxes = np.array([[0, 0, 2, 2], [1, 1, 3, 2]], dtype=np.int32)
    >>> weights = np.array([1.0, 0.5], dtype=np.float32)
    >>> accumulate_heat(boxes, weights, 2, 3)
    array([[1. , 1. , 0. ],
           [1. , 1.5, 0.5]], dtype=float32)
    """
    heat = np.zeros((height, width), dtype=np.float32)
    accumulate_heat_into(heat, boxes, weights)
    return heat
