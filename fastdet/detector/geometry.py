"""Box geometry shared by tracking, evaluation and mining: areas, intersections, IoU, cover.

Boxes are ``[x1, y1, x2, y2]`` pixels with exclusive ``x2``/``y2`` (the
convention of :class:`~fastdet.detector.detections.Detections` and of the
annotation files), so a box's area is ``(x2 - x1) * (y2 - y1)``.  Every
function takes array-likes of shape ``(N, 4)`` and works in float64.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError


def iou_matrix(boxes_a, boxes_b):
    """Intersection over union of every pair of boxes.

    Parameters
    ----------
    boxes_a : array_like, shape (N, 4)
        ``[x1, y1, x2, y2]`` boxes, ``x2``/``y2`` exclusive.
    boxes_b : array_like, shape (M, 4)
        Same convention.

    Returns
    -------
    ndarray of float64, shape (N, M)
        ``iou[i, j]`` of ``boxes_a[i]`` and ``boxes_b[j]``; 0 for pairs that
        do not overlap or whose union is empty (degenerate boxes).
    """
    boxes_a = as_box_array(boxes_a, "boxes_a")
    boxes_b = as_box_array(boxes_b, "boxes_b")
    area_a = box_areas(boxes_a)
    area_b = box_areas(boxes_b)
    intersection = _intersections(boxes_a, boxes_b)
    union = area_a[:, None] + area_b[None, :] - intersection
    iou = np.zeros_like(intersection)
    np.divide(intersection, union, out=iou, where=union > 0)
    return iou


def iou_rows(boxes_a, boxes_b):
    """:func:`iou_matrix` of a few boxes, in plain Python.

    For the tracker, which matches a frame's handful of boxes every frame
    with the GIL held: the NumPy version's twenty-odd array operations take
    about 27 us on two boxes against two, this about 6 us (the ``tolist``
    of both included).  The values are the same: for integer boxes every
    term is an exact integer, as it is in :func:`iou_matrix`'s float64, up
    to the one correctly rounded division.

    Parameters
    ----------
    boxes_a, boxes_b : sequence of sequence of int
        ``[x1, y1, x2, y2]`` boxes (e.g. ``array.tolist()`` of int boxes),
        ``x2``/``y2`` exclusive.

    Returns
    -------
    list of list of float
        ``iou[i][j]`` of ``boxes_a[i]`` and ``boxes_b[j]``; 0.0 for pairs that
        do not overlap or whose union is empty.
    """
    areas_b = [max(x2 - x1, 0) * max(y2 - y1, 0) for x1, y1, x2, y2 in boxes_b]
    rows = []
    for ax1, ay1, ax2, ay2 in boxes_a:
        area_a = max(ax2 - ax1, 0) * max(ay2 - ay1, 0)
        row = []
        for (bx1, by1, bx2, by2), area_b in zip(boxes_b, areas_b):
            overlap = (max(min(ax2, bx2) - max(ax1, bx1), 0)
                       * max(min(ay2, by2) - max(ay1, by1), 0))
            union = area_a + area_b - overlap
            row.append(overlap / union if union > 0 else 0.0)
        rows.append(row)
    return rows


def cover_matrix(boxes_a, boxes_b):
    """Share of each box of ``boxes_a`` lying inside each box of ``boxes_b``.

    Returns
    -------
    ndarray of float64, shape (N, M)
        ``intersection(a_i, b_j) / area(a_i)``; 0 where ``a_i`` has no area.
    """
    boxes_a = as_box_array(boxes_a, "boxes_a")
    intersection = _intersections(boxes_a, as_box_array(boxes_b, "boxes_b"))
    area = box_areas(boxes_a)[:, None]
    cover = np.zeros_like(intersection)
    np.divide(intersection, area, out=cover, where=area > 0)
    return cover


def as_box_array(boxes, name):
    boxes = np.asarray(boxes, dtype=np.float64)
    if boxes.size == 0:
        return boxes.reshape(0, 4)
    if boxes.ndim != 2 or boxes.shape[1] != 4:
        raise InputError(f"{name} must have shape (N, 4), got {boxes.shape}")
    return boxes


def box_areas(boxes):
    # Inverted boxes get zero area rather than a negative one.  np.maximum rather
    # than np.clip: the same values, without np.clip's dispatch (a few microseconds
    # a call, which the tracker pays several times a frame on a handful of boxes).
    return (np.maximum(boxes[:, 2] - boxes[:, 0], 0)
            * np.maximum(boxes[:, 3] - boxes[:, 1], 0))


def intersection_matrix(boxes_a, boxes_b):
    """Intersection area of every pair of boxes (float64, shape (N, M))."""
    return _intersections(as_box_array(boxes_a, "boxes_a"), as_box_array(boxes_b, "boxes_b"))


def _intersections(boxes_a, boxes_b):
    """:func:`intersection_matrix` of two float64 ``(N, 4)`` arrays."""
    # Broadcast (N, 1) against (1, M): overlap extents of every pair.
    overlap_w = (np.minimum(boxes_a[:, None, 2], boxes_b[None, :, 2])
                 - np.maximum(boxes_a[:, None, 0], boxes_b[None, :, 0]))
    overlap_h = (np.minimum(boxes_a[:, None, 3], boxes_b[None, :, 3])
                 - np.maximum(boxes_a[:, None, 1], boxes_b[None, :, 1]))
    return np.maximum(overlap_w, 0) * np.maximum(overlap_h, 0)
