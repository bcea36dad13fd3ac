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
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = [
    "component_boxes",
    "component_core_boxes",
    "component_max",
    "label_components",
    "label_components_kernel",
    "split_component",
]


@numba.njit(cache=True, inline="always")
def _find_root(parent, label):
    # Path halving keeps trees shallow without a second pass or recursion.
    while parent[label] != label:
        parent[label] = parent[parent[label]]
        label = parent[label]
    return label


@numba.njit(cache=True, inline="always")
def _union(parent, label_a, label_b):
    root_a = _find_root(parent, label_a)
    root_b = _find_root(parent, label_b)
    # Smaller label wins so that roots stay the first-seen label (see module
    # docstring: this is what makes the numbering match scipy).
    if root_a < root_b:
        parent[root_b] = root_a
    elif root_b < root_a:
        parent[root_a] = root_b


@numba.njit(cache=True)
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
    labels = np.zeros((height, width), dtype=np.int32)
    parent = np.empty(height * ((width + 1) // 2) + 1, dtype=np.int32)
    parent[0] = 0
    next_label = 1

    for y in range(height):
        for x in range(width):
            if not mask[y, x]:
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
    return labels, count


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


@numba.njit(cache=True, inline="always")
def _sentinel_boxes(count, width, height):
    """Boxes with inverted bounds, so the first included pixel sets every bound."""
    boxes = np.empty((count, 4), dtype=np.int32)
    boxes[:, 0] = width
    boxes[:, 1] = height
    boxes[:, 2] = 0
    boxes[:, 3] = 0
    return boxes


@numba.njit(cache=True, inline="always")
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


@numba.njit(cache=True, inline="always")
def _zero_unused(boxes):
    """Boxes that never included a pixel become [0, 0, 0, 0]."""
    for row in range(boxes.shape[0]):
        if boxes[row, 2] == 0:
            boxes[row, :] = 0


@numba.njit(cache=True)
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
    height, width = labels.shape
    boxes = _sentinel_boxes(count, width, height)
    for y in range(height):
        for x in range(width):
            label = labels[y, x]
            if 0 < label <= count:
                _include(boxes, label - 1, x, y)
    _zero_unused(boxes)
    return boxes


@numba.njit(cache=True)
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
    maxima = np.full(count, -np.inf, dtype=np.float32)
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


@numba.njit(cache=True)
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


@numba.njit(cache=True)
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
    mask : ndarray of bool or uint8, shape (h, w)
        The blob's pixels.
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
    above = np.zeros((height, width), dtype=np.uint8)
    for level_index in range(levels.size):
        level = levels[level_index]
        for y in range(height):
            for x in range(width):
                above[y, x] = 1 if (mask[y, x] and heat[y, x] > level) else 0
        labels, count = label_components_kernel(above, connectivity == 8)
        if count < 2:
            if count == 0:
                break
            continue
        parts = component_boxes(labels, count)
        big = 0
        for k in range(count):
            if (parts[k, 2] - parts[k, 0] >= min_width
                    and parts[k, 3] - parts[k, 1] >= min_height):
                big += 1
        if big < 2:
            continue
        seeds = np.empty((big, 4), dtype=np.int32)
        n = 0
        for k in range(count):
            if (parts[k, 2] - parts[k, 0] >= min_width
                    and parts[k, 3] - parts[k, 1] >= min_height):
                seeds[n] = parts[k]
                n += 1
        out = _sentinel_boxes(big, width, height)
        for y in range(height):
            for x in range(width):
                if not mask[y, x]:
                    continue
                best = 0
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
    whole = _sentinel_boxes(1, width, height)
    for y in range(height):
        for x in range(width):
            if mask[y, x]:
                _include(whole, 0, x, y)
    _zero_unused(whole)
    return whole
