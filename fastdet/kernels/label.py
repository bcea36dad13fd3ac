"""Connected-component labelling of binary masks and per-component reductions.

Thresholded heat maps are split into vehicle blobs by labelling their
connected components; the blobs' bounding boxes and peak heat become the
final detections.

Algorithm
---------
``label_components`` is the classic two-pass union-find labelling:

1. Raster scan.  Each foreground pixel looks only at its already visited
   neighbours (left and up for 4-connectivity; left, up-left, up and
   up-right for 8-connectivity).  Without a labelled neighbour it gets a new
   provisional label, otherwise it copies one and merges the provisional
   labels of neighbours that are not yet known to be connected (e.g. the two
   arms of a "U" meeting at its bottom).  For 8-connectivity a decision tree
   exploits that neighbours adjacent to each other are already merged, so at
   most one union is needed per pixel.
2. Resolution.  Union-find trees always hang the larger provisional label
   under the smaller, so every root is the smallest provisional label of its
   component.  That label was created at the component's first pixel in
   raster order (that pixel cannot have an earlier neighbour in the same
   component), hence numbering roots in increasing order numbers components
   by the raster position of their first pixel -- the same numbering as
   ``scipy.ndimage.label``.  One ascending pass maps every provisional label
   to its final number (a parent is always smaller, so it is already
   resolved), and a final raster pass rewrites the label image.

Work is O(H * W) (up to the inverse-Ackermann factor of union-find with path
halving).  A new provisional label needs a background (or missing) left
neighbour, so a row creates at most ``ceil(W / 2)`` of them; this bounds the
union-find table to ``H * ceil(W / 2) + 1`` entries.

``component_boxes`` and ``component_max`` are single raster passes that
reduce over the label image.

Heat blobs
----------
``heat_blobs`` does the detector's whole thresholding step in one call, at
the resolution the heat actually has.  A heat map made of boxes only changes
at box edges, so ``constant_runs`` cuts it (by comparing bit patterns of
adjacent rows and columns, which needs no knowledge of the boxes) into a
grid of cells, each constant.  Labelling the cells gives exactly the pixel
labelling: a cell's pixels are alike, two cells' pixels touch (for 4- or
8-connectivity) exactly when the cells do, and the first pixel of a
component in raster order is the top-left pixel of its first cell in raster
order, so even the numbering agrees.  Maxima and (core) boxes follow from
the cells' values and pixel bounds, and the sub-sampled split probe runs on
the cells the samples fall in.

Compile time
------------
``heat_blobs`` is the costliest kernel to compile of a detection.  Numba
compiles every ``@njit`` callee on its own and optimises its code again in
each caller, so the small helpers called from one place in that tree are
``inline="always"`` (inlined in Numba's IR, compiled once, with their
caller): the family's first compile went from 8.8 to 6.7 s on an AMD EPYC
(Zen 3).  Helpers called from several places (labelling, the component
boxes) stay separate: inlining those made it slower (10.7-11.3 s).  Without
``np.full`` and the float map's ``view``, which Numba compiled as functions
of their own, it takes 4.8-5.0 s (5.6-5.8 s before; 3 runs each, Numba's own set-up
not counted).  ``heat_blobs`` labels through ``_label_into`` directly: through
``label_components_kernel``, a thin wrapper, Numba also compiled the wrapper and
optimised the labelling code once more in it (4.7-4.9 s against 5.0-5.1 s, Numba's
set-up counted, 3 alternating runs).
"""

from __future__ import annotations

import numba
import numpy as np
from llvmlite import ir
from numba.core import types
from numba.extending import intrinsic

from .alloc import empty, full, zeros
from .inner import CALLED_FROM_KERNELS_ONLY

__all__ = [
    "component_boxes",
    "component_core_boxes",
    "component_max",
    "constant_runs",
    "heat_blobs",
    "label_components",
    "label_components_kernel",
    "split_component",
    "split_levels",
]


@numba.njit(cache=True, nogil=True, **CALLED_FROM_KERNELS_ONLY)
def _find_root(parent, label):
    # Path halving keeps trees shallow without a second pass or recursion.
    while parent[label] != label:
        parent[label] = parent[parent[label]]
        label = parent[label]
    return label


@numba.njit(cache=True, nogil=True, **CALLED_FROM_KERNELS_ONLY)
def _union(parent, label_a, label_b):
    root_a = _find_root(parent, label_a)
    root_b = _find_root(parent, label_b)
    # Smaller label wins so that roots stay the first-seen label (see module
    # docstring: this is what makes the numbering match scipy).
    if root_a < root_b:
        parent[root_b] = root_a
    elif root_b < root_a:
        parent[root_a] = root_b


@numba.njit(cache=True, nogil=True)
def label_components_kernel(mask, eight_connected):
    """Label connected components of a 2-D mask (jitted core, no validation).

    Callable from other jitted code; from Python prefer
    :func:`label_components`, which validates its arguments.

    Parameters
    ----------
    mask : numpy.ndarray
        2-D array of shape ``(H, W)``; nonzero / True pixels are foreground.
    eight_connected : bool
        True for 8-connectivity (full 3x3 neighbourhood), False for
        4-connectivity (cross).

    Returns
    -------
    labels : numpy.ndarray
        int32 array of shape ``(H, W)``; 0 is background, components are
        numbered ``1..count`` in raster order of their first pixel.
    count : int
        Number of components.
    """
    height, width = mask.shape
    labels = empty((height, width), dtype=np.int32)
    parent = empty(_parent_size(height, width), dtype=np.int32)
    count = _label_into(mask, eight_connected, labels, parent)
    return labels, count


@numba.njit(cache=True, nogil=True, inline="always")
def _parent_size(height, width):
    return height * ((width + 1) // 2) + 1


@numba.njit(cache=True, nogil=True, **CALLED_FROM_KERNELS_ONLY)
def _label_into(mask, eight_connected, labels, parent):
    """:func:`label_components_kernel` into given buffers; returns the count.

    ``labels`` is ``mask``'s shape (any content), ``parent`` has at least
    ``_parent_size(*mask.shape)`` entries.
    """
    height, width = mask.shape
    parent[0] = 0
    next_label = 1

    for y in range(height):
        for x in range(width):
            if not mask[y, x]:
                labels[y, x] = 0
                continue
            up = labels[y - 1, x] if y > 0 else 0
            left = labels[y, x - 1] if x > 0 else 0
            if eight_connected:
                if up != 0:
                    # `up` touches all other visited neighbours, which are
                    # therefore already merged with it.
                    label = up
                else:
                    up_left = labels[y - 1, x - 1] if y > 0 and x > 0 else 0
                    up_right = labels[y - 1, x + 1] if y > 0 and x + 1 < width else 0
                    if up_right != 0:
                        label = up_right
                        # up_left and left touch each other (already merged)
                        # but not up_right, so one union suffices.
                        if up_left != 0:
                            if up_left != up_right:
                                _union(parent, up_right, up_left)
                        elif left != 0 and left != up_right:
                            _union(parent, up_right, left)
                    elif up_left != 0:
                        label = up_left
                    elif left != 0:
                        label = left
                    else:
                        label = next_label
                        parent[next_label] = next_label
                        next_label += 1
            else:
                if up != 0:
                    label = up
                    if left != 0 and left != up:
                        _union(parent, up, left)
                elif left != 0:
                    label = left
                else:
                    label = next_label
                    parent[next_label] = next_label
                    next_label += 1
            labels[y, x] = label

    # Ascending pass: parents are smaller than their children, so
    # parent[parent_label] already holds the final number when we read it.
    count = 0
    for provisional in range(1, next_label):
        parent_label = parent[provisional]
        if parent_label == provisional:
            count += 1
            parent[provisional] = count
        else:
            parent[provisional] = parent[parent_label]

    for y in range(height):
        for x in range(width):
            labels[y, x] = parent[labels[y, x]]
    return count


def label_components(mask, connectivity):
    """Label connected components of a 2-D binary mask.

    The result is identical to ``scipy.ndimage.label(mask, structure)`` with
    the cross (4) or full 3x3 (8) structuring element, including the label
    numbering.

    Parameters
    ----------
    mask : array_like
        2-D array of shape ``(H, W)``, normally bool or uint8 and
        C-contiguous; nonzero pixels are foreground.  Other dtypes or
        layouts are converted (copied) first.
    connectivity : {4, 8}
        Pixel neighbourhood: 4 for edge neighbours only, 8 to include
        diagonals.

    Returns
    -------
    labels : numpy.ndarray
        int32 array of shape ``(H, W)``; 0 is background, components are
        numbered ``1..count`` in raster order of their first pixel.
    count : int
        Number of components.

    Raises
    ------
    ValueError
        If ``connectivity`` is not 4 or 8, or ``mask`` is not 2-D.

    See Also
    --------
    label_components_kernel : The jitted core, callable from Numba code.

    Examples
    --------
    >>> mask = np.array([[1, 0, 1],
    ...                  [0, 1, 0]], dtype=bool)
    >>> label_components(mask, 4)[1], label_components(mask, 8)[1]
    (3, 1)
    """
    if connectivity not in (4, 8):
        raise ValueError(f"connectivity must be 4 or 8, got {connectivity!r}")
    mask = np.asarray(mask)
    if mask.ndim != 2:
        raise ValueError(f"mask must be 2-D, got shape {mask.shape}")
    # Funnel every input into C-contiguous uint8 so the kernel is compiled
    # (and cached) once; bool -> uint8 is a zero-copy view.
    if mask.dtype == np.bool_:
        mask = np.ascontiguousarray(mask).view(np.uint8)
    elif mask.dtype == np.uint8:
        mask = np.ascontiguousarray(mask)
    else:
        mask = np.ascontiguousarray(mask != 0).view(np.uint8)
    labels, count = label_components_kernel(mask, connectivity == 8)
    return labels, int(count)


@numba.njit(cache=True, nogil=True, inline="always")
def _sentinel_boxes(count, width, height):
    """Boxes with inverted bounds, so the first included pixel sets every bound."""
    boxes = empty((count, 4), dtype=np.int32)
    boxes[:, 0] = width
    boxes[:, 1] = height
    boxes[:, 2] = 0
    boxes[:, 3] = 0
    return boxes


@numba.njit(cache=True, nogil=True, inline="always")
def _include(boxes, row, x, y):
    """Grow box ``row`` to contain pixel (x, y)."""
    if x < boxes[row, 0]:
        boxes[row, 0] = x
    if y < boxes[row, 1]:
        boxes[row, 1] = y
    if x + 1 > boxes[row, 2]:
        boxes[row, 2] = x + 1
    if y + 1 > boxes[row, 3]:
        boxes[row, 3] = y + 1


@numba.njit(cache=True, nogil=True, inline="always")
def _zero_unused(boxes):
    """Boxes that never included a pixel become [0, 0, 0, 0]."""
    for row in range(boxes.shape[0]):
        if boxes[row, 2] == 0:
            boxes[row, :] = 0


@numba.njit(cache=True, nogil=True, **CALLED_FROM_KERNELS_ONLY)
def _component_boxes(labels, count):
    """:func:`component_boxes`, for kernels: Numba builds no Python wrappers
    for it, which a detection's compile would pay for and never use."""
    height, width = labels.shape
    boxes = _sentinel_boxes(count, width, height)
    for y in range(height):
        for x in range(width):
            label = labels[y, x]
            if 0 < label <= count:
                _include(boxes, label - 1, x, y)
    _zero_unused(boxes)
    return boxes


@numba.njit(cache=True, nogil=True)
def component_boxes(labels, count):
    """Bounding boxes of labelled components.

    Parameters
    ----------
    labels : numpy.ndarray
        Integer array of shape ``(H, W)`` as returned by
        :func:`label_components`.  Values outside ``1..count`` (including
        the background 0) are ignored.
    count : int
        Number of labels; must be >= 0.

    Returns
    -------
    numpy.ndarray
        int32 array of shape ``(count, 4)``; row ``k`` is
        ``[x1, y1, x2, y2]`` (``x2``, ``y2`` exclusive) of label ``k + 1``.
        Labels without any pixel get ``[0, 0, 0, 0]``.
    """
    return _component_boxes(labels, count)


@numba.njit(cache=True, nogil=True, inline="always")
def component_max(labels, count, values):
    """Maximum of ``values`` over each labelled component.

    Parameters
    ----------
    labels : numpy.ndarray
        Integer array of shape ``(H, W)`` as returned by
        :func:`label_components`.  Values outside ``1..count`` (including
        the background 0) are ignored.
    count : int
        Number of labels; must be >= 0.
    values : numpy.ndarray
        float32 array with the same shape as ``labels`` (not checked).

    Returns
    -------
    numpy.ndarray
        float32 array of shape ``(count,)``; entry ``k`` is the maximum of
        ``values`` over label ``k + 1``.  NaN propagates like ``numpy.max``;
        labels without any pixel get ``-inf``.
    """
    height, width = labels.shape
    maxima = full(count, -np.inf, np.float32)
    for y in range(height):
        for x in range(width):
            label = labels[y, x]
            if label <= 0 or label > count:
                continue
            value = np.float32(values[y, x])
            # `value != value` is the NaN test; once NaN is stored, `>` is
            # always False, so NaN sticks like in numpy.max.
            if value > maxima[label - 1] or value != value:
                maxima[label - 1] = value
    return maxima


@numba.njit(cache=True, nogil=True, inline="always")
def component_core_boxes(labels, count, values, thresholds):
    """Bounding boxes of each component's core: its pixels with value >= a threshold.

    Used to tighten boxes: a component is found with a low heat threshold,
    and its box is taken from where the heat reaches a fraction of its peak.

    Parameters
    ----------
    labels : numpy.ndarray
        Integer array of shape ``(H, W)`` from :func:`label_components`.
    count : int
        Number of labels.
    values : numpy.ndarray
        float32 array of shape ``(H, W)``.
    thresholds : numpy.ndarray
        float32 array of shape ``(count,)``: the core threshold of label
        ``k + 1`` at index ``k``.

    Returns
    -------
    numpy.ndarray
        int32 array of shape ``(count, 4)``, ``[x1, y1, x2, y2]`` exclusive;
        ``[0, 0, 0, 0]`` for a label with no pixel at or above its threshold.
    """
    height, width = labels.shape
    boxes = _sentinel_boxes(count, width, height)
    for y in range(height):
        for x in range(width):
            label = labels[y, x]
            if 0 < label <= count and values[y, x] >= thresholds[label - 1]:
                _include(boxes, label - 1, x, y)
    _zero_unused(boxes)
    return boxes


@numba.njit(cache=True, nogil=True)
def split_component(heat, mask, levels, min_width, min_height, connectivity):
    """Split one heat blob into car-sized parts at the lowest level that separates it.

    Two cars side by side make one blob with a valley between two peaks.
    The threshold is raised through ``levels`` until the blob's pixels above
    it fall into two or more parts whose boxes are each at least
    ``min_width x min_height``; every pixel of the blob is then given to the
    part whose box is nearest, so the parts share the blob's full extent.

    Parameters
    ----------
    heat : ndarray of float32, shape (h, w)
        Heat around the blob.
    mask : ndarray of uint8, shape (h, w)
        The blob's pixels (1), C-contiguous; a bool mask can be passed as
        ``mask.view(np.uint8)`` (one compiled version serves both).
    levels : ndarray of float32
        Increasing thresholds to try.
    min_width, min_height : int
        Smallest part that counts as a car.
    connectivity : int
        4 or 8.

    Returns
    -------
    ndarray of int32, shape (n, 4)
        Boxes ``[x1, y1, x2, y2]`` of the parts, or one row (the blob's box)
        when no level splits it into car-sized parts.
    """
    height, width = heat.shape
    seeds = _car_sized_parts(heat, mask, np.arange(height + 1), np.arange(width + 1), levels,
                             min_width, min_height, connectivity == 8)
    big = seeds.shape[0]
    if big >= 2:
        out = _sentinel_boxes(big, width, height)
        for y in range(height):
            for x in range(width):
                if not mask[y, x]:
                    continue
                best = np.int64(0)  # not the literal 0: one type for best
                best_distance = np.inf
                for k in range(big):
                    dx = max(seeds[k, 0] - x, 0, x - (seeds[k, 2] - 1))
                    dy = max(seeds[k, 1] - y, 0, y - (seeds[k, 3] - 1))
                    distance = dx * dx + dy * dy
                    if distance < best_distance:
                        best_distance = distance
                        best = k
                _include(out, best, x, y)
        _zero_unused(out)
        return out
    # Counts as variables, not constants: Numba would compile the helpers
    # again for each literal value.
    one, first = np.int64(1), np.int64(0)
    whole = _sentinel_boxes(one, width, height)
    for y in range(height):
        for x in range(width):
            if mask[y, x]:
                _include(whole, first, x, y)
    _zero_unused(whole)
    return whole


# -- heat blobs on the grid of constant cells ----------------------------------


@intrinsic
def _bit_pattern(typingctx, value):
    """A float's bits as an unsigned integer of its size (an integer as it is).

    Reinterpreting each value read costs one register move; a view of the
    whole array (``values.view(np.uint32)``) compiled Numba's ``view``
    implementation on its own, 0.4 s of the family's first compile.
    """
    if isinstance(value, types.Float):
        width = value.bitwidth

        def codegen(context, builder, signature, args):
            return builder.bitcast(args[0], ir.IntType(width))

        return (types.uint32 if width == 32 else types.uint64)(value), codegen
    if isinstance(value, types.Integer):
        return value(value), lambda context, builder, signature, args: args[0]
    return None


@numba.njit(cache=True, nogil=True, inline="always")
def constant_runs(bits):
    """Runs of identical adjacent rows and of identical adjacent columns.

    A heat map made of boxes is piecewise constant: it only changes at box
    edges.  Cutting it where a row (column) differs from the one before it
    gives a grid of cells on each of which every pixel is the same.

    Parameters
    ----------
    bits : numpy.ndarray
        2-D float or integer array of shape ``(H, W)``: floats are compared
        by their bit patterns, so that "identical" means identical bits
        (``-0.0`` and ``0.0`` differ, equal NaNs match).

    Returns
    -------
    row_starts : numpy.ndarray
        int64 array ``(R + 1,)``: the first row of each run of identical
        rows, then ``H``.  Row ``y`` of a run equals row ``row_starts[i]``.
    col_starts : numpy.ndarray
        int64 array ``(C + 1,)``: the first column of each run of columns
        identical over all rows, then ``W``.
    """
    height, width = bits.shape
    row_starts = empty(height + 1, dtype=np.int64)
    new_column = zeros(width + 1, dtype=np.bool_)
    new_column[0] = True
    n_rows = 0
    for y in range(height):
        if y > 0:
            differs = False
            for x in range(width):
                differs |= _bit_pattern(bits[y, x]) != _bit_pattern(bits[y - 1, x])
            if not differs:
                continue
        row_starts[n_rows] = y
        n_rows += 1
        # Columns only need comparing on the first row of a run (the others
        # are copies), while it is still in cache.
        for x in range(1, width):
            new_column[x] |= _bit_pattern(bits[y, x]) != _bit_pattern(bits[y, x - 1])
    row_starts[n_rows] = height
    n_cols = 0
    for x in range(width):
        n_cols += new_column[x]
    col_starts = empty(n_cols + 1, dtype=np.int64)
    n_cols = 0
    for x in range(width):
        if new_column[x]:
            col_starts[n_cols] = x
            n_cols += 1
    col_starts[n_cols] = width
    return row_starts[:n_rows + 1], col_starts


# Inlined: each of its two callers (heat_blobs' probe, split_component) is
# in a family of its own, so it is typed once per family either way, and is
# not optimised a second time in its caller (the split family compiles in
# 3.5-3.6 s against 3.8 s; the label family's time did not move).
@numba.njit(cache=True, nogil=True, inline="always")
def _car_sized_parts(values, mask, row_units, col_units, levels, min_width, min_height,
                     eight_connected):
    """The car-sized parts of a blob at the lowest level that gives two or more.

    Cell ``(i, j)`` of ``values`` / ``mask`` stands for the units
    ``[row_units[i], row_units[i + 1]) x [col_units[j], col_units[j + 1])``,
    all alike (unit steps: plain pixels).  Labelling commutes with that
    expansion (cells touch exactly where their units do), so the parts are
    unions of cells and their sizes follow from the cells' unit bounds.

    Returns
    -------
    ndarray of int32, shape (n, 4)
        Cell boxes ``[x1, y1, x2, y2]`` of the parts at least
        ``min_width x min_height`` units; ``n`` is 0 when no level splits.
    """
    height, width = values.shape
    above = empty((height, width), dtype=np.uint8)
    labels = empty((height, width), dtype=np.int32)
    parent = empty(_parent_size(height, width), dtype=np.int32)
    for level_index in range(levels.size):
        level = levels[level_index]
        for i in range(height):
            for j in range(width):
                above[i, j] = 1 if (mask[i, j] and values[i, j] > level) else 0
        count = _label_into(above, eight_connected, labels, parent)
        if count < 2:
            if count == 0:
                break
            continue
        parts = _component_boxes(labels, count)
        car_sized = zeros(count, dtype=np.bool_)
        n_car_sized = 0
        for k in range(count):
            car_sized[k] = (col_units[parts[k, 2]] - col_units[parts[k, 0]] >= min_width
                            and row_units[parts[k, 3]] - row_units[parts[k, 1]] >= min_height)
            n_car_sized += car_sized[k]
        if n_car_sized >= 2:
            return parts[car_sized]
    return zeros((0, 4), dtype=np.int32)


@numba.njit(cache=True, nogil=True, inline="always")
def _splits(values, mask, row_units, col_units, levels, min_width, min_height,
            eight_connected):
    """Whether :func:`split_component` would split this blob, decided on its
    grid of constant cells (see :func:`_car_sized_parts`)."""
    return _car_sized_parts(values, mask, row_units, col_units, levels, min_width, min_height,
                            eight_connected).shape[0] >= 2


@numba.njit(cache=True, nogil=True, inline="always")
def _samples(starts, first, last, index0, step):
    """Which cells the sampled units ``first, first + step, ... < last`` fall in.

    Consecutive samples in one cell are merged.  Returns the cells and the
    first sample number of each (then the sample count).
    """
    n_samples = (last - first + step - 1) // step
    cells = empty(n_samples, dtype=np.int64)
    units = empty(n_samples + 1, dtype=np.int64)
    n = 0
    cell = index0
    for sample in range(n_samples):
        position = first + sample * step
        while starts[cell + 1] <= position:
            cell += 1
        if n == 0 or cells[n - 1] != cell:
            cells[n] = cell
            units[n] = sample
            n += 1
    units[n] = n_samples
    return cells[:n], units[:n + 1]


@numba.njit(cache=True, nogil=True, inline="always")
def split_levels(peak, threshold64, fractions):
    """Thresholds at which a blob is split, as ``heat_components`` computes them.

    ``float32(threshold64 + float64(peak - float32(threshold64)) * fractions)``:
    NumPy's ``(threshold + (peak - threshold) * fractions).astype(float32)``
    for a float32 ``peak``, a Python float ``threshold`` and float64
    ``fractions`` (the subtraction is float32 under NumPy 2 promotion).
    """
    rise = np.float64(np.float32(peak) - np.float32(threshold64))
    levels = empty(fractions.size, dtype=np.float32)
    for index in range(fractions.size):
        levels[index] = np.float32(threshold64 + rise * fractions[index])
    return levels


@numba.njit(cache=True, nogil=True)
def heat_blobs(heat, origin_x, origin_y, threshold, eight_connected, refine, core_fraction,
               split_size, probe_step, level_fractions):
    """Threshold, label and measure the blobs of a heat map in one pass.

    The same as labelling ``heat > threshold`` at full resolution
    (:func:`label_components`), reducing the labels with
    :func:`component_max` and :func:`component_boxes` or
    :func:`component_core_boxes`, and running the sub-sampled split probe
    (:func:`split_component` on every ``probe_step``-th pixel of a large
    blob), but done on the grid of constant cells (:func:`constant_runs`)
    covering the above-threshold heat.  Cells are exact stand-ins for their
    pixels: a cell's pixels are all alike, cells touch (also diagonally)
    exactly where their pixels do, and the first pixel of a component in
    raster order is the first pixel of its first cell in raster order, so
    components, their numbering, maxima and boxes all agree.

    Parameters
    ----------
    heat : numpy.ndarray
        2-D float32 or float64 array ``(H, W)``, any layout.
    origin_x, origin_y : int
        Added to the returned boxes (the map's position in the frame).
    threshold : float
        Foreground is ``heat > threshold``, compared in ``heat``'s precision
        (as NumPy compares an array with a Python float); the split levels
        are derived from it by :func:`split_levels`.
    eight_connected : bool
        8- (True) or 4-connectivity.
    refine : bool
        Return each blob's core box (its pixels whose heat is at least
        ``peak * core_fraction``, in float32) instead of its whole box.
    core_fraction : numpy.float32
        See ``refine``.
    split_size : int
        Smallest car side in pixels.  A blob at least twice that wide or
        tall is probed; negative: nothing is probed.
    probe_step : int
        Sub-sampling of the probe; a car is ``max(1, split_size //
        probe_step)`` samples.
    level_fractions : numpy.ndarray
        float64 fractions passed to :func:`split_levels`.

    Returns
    -------
    boxes : numpy.ndarray
        int32 ``(n, 4)`` ``[x1, y1, x2, y2]`` (exclusive ends) plus the
        origin, blobs numbered like :func:`label_components`.
    peaks : numpy.ndarray
        float32 ``(n,)`` maximum heat of each blob.
    probed : numpy.ndarray
        bool ``(n,)``: the probe split the blob into car-sized parts.
    n_probed : int
        How many blobs did.
    """
    threshold64 = np.float64(threshold)
    # The threshold rounded to heat's type, as an array assignment rounds it.
    typed = empty(1, dtype=heat.dtype)
    typed[0] = threshold64
    threshold = typed[0]
    all_rows, all_cols = constant_runs(heat)
    # Cells above the threshold, and their bounding box: only it is labelled.
    top, bottom, left, right = all_rows.size, -1, all_cols.size, -1
    for i in range(all_rows.size - 1):
        y = all_rows[i]
        for j in range(all_cols.size - 1):
            if heat[y, all_cols[j]] > threshold:
                top = min(top, i)
                bottom = max(bottom, i)
                left = min(left, j)
                right = max(right, j)
    if bottom < 0:
        top, bottom, left, right = 0, -1, 0, -1
    row_starts = all_rows[top:bottom + 2]
    col_starts = all_cols[left:right + 2]
    n_rows, n_cols = bottom + 1 - top, right + 1 - left
    values = empty((n_rows, n_cols), dtype=heat.dtype)
    mask = empty((n_rows, n_cols), dtype=np.uint8)
    for i in range(n_rows):
        for j in range(n_cols):
            value = heat[row_starts[i], col_starts[j]]
            values[i, j] = value
            mask[i, j] = 1 if value > threshold else 0
    # _label_into, not label_components_kernel (see "Compile time" above).
    labels = empty((n_rows, n_cols), dtype=np.int32)
    count = _label_into(mask, eight_connected, labels,
                        empty(_parent_size(n_rows, n_cols), dtype=np.int32))

    cell_boxes = _component_boxes(labels, count)
    peaks = component_max(labels, count, values)
    probed = zeros(count, dtype=np.bool_)
    n_probed = 0
    if split_size >= 0:
        probe_size = max(1, split_size // probe_step)
        for k in range(count):
            x1, x2 = col_starts[cell_boxes[k, 0]], col_starts[cell_boxes[k, 2]]
            y1, y2 = row_starts[cell_boxes[k, 1]], row_starts[cell_boxes[k, 3]]
            if max(x2 - x1, y2 - y1) < 2 * split_size:
                continue
            # The probe's sub-sampled image, runs of samples in one cell merged.
            sample_rows, row_units = _samples(row_starts, y1, y2, cell_boxes[k, 1], probe_step)
            sample_cols, col_units = _samples(col_starts, x1, x2, cell_boxes[k, 0], probe_step)
            sub_values = empty((sample_rows.size, sample_cols.size), dtype=heat.dtype)
            sub_mask = empty((sample_rows.size, sample_cols.size), dtype=np.uint8)
            for i in range(sample_rows.size):
                for j in range(sample_cols.size):
                    sub_values[i, j] = values[sample_rows[i], sample_cols[j]]
                    sub_mask[i, j] = 1 if labels[sample_rows[i], sample_cols[j]] == k + 1 else 0
            probed[k] = _splits(sub_values, sub_mask, row_units, col_units,
                                split_levels(peaks[k], threshold64, level_fractions),
                                probe_size, probe_size, eight_connected)
            n_probed += probed[k]

    if refine:
        core = empty(count, dtype=np.float32)
        for k in range(count):
            core[k] = peaks[k] * core_fraction
        cell_boxes = component_core_boxes(labels, count, values, core)
    # An empty core box ([0, 0, 0, 0] in cells) becomes an empty box at the
    # corner of the labelled cells, as at full resolution on the cropped map.
    boxes = empty((count, 4), dtype=np.int32)
    for k in range(count):
        boxes[k, 0] = col_starts[cell_boxes[k, 0]] + origin_x
        boxes[k, 1] = row_starts[cell_boxes[k, 1]] + origin_y
        boxes[k, 2] = col_starts[cell_boxes[k, 2]] + origin_x
        boxes[k, 3] = row_starts[cell_boxes[k, 3]] + origin_y
    return boxes, peaks, probed, n_probed
