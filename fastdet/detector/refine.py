"""Box refinement: each box's edges from the shape of its heat, by a fitted linear model.

A heat blob's box is only as precise as the window grid (windows step by a
quarter to a half of their side), and square windows overhang wide cars.
The blob's heat says more: where its upper levels lie, where its mass is
centred and how far it spreads.  And where the box lies says how the
vehicle is seen: a large box low in the frame is a near vehicle, a box far
to the side one seen at an angle, its side in view (so its box reaches
beyond the rear the classifier fires on).  :func:`heat_features` measures
that, in units of the box and of the frame height (so a model fitted on one
frame size applies to another), and :func:`refine_boxes` maps the features
linearly to the four edges: ``edges = features @ weights.T``, each edge as
an offset from the box centre in box widths (x) or heights (y).

A vehicle left of the middle is the mirror image of one on the right (the
side in view is the other one), so boxes left of the middle column are
measured, and their edges placed, in the mirrored frame: one model serves
both sides, even if the frames it was fitted on had vehicles on one side
only.  ``fastdet tune`` fits the weights on annotated frames
(:func:`fastdet.training.refine.fit_refinement`).
"""

from __future__ import annotations

import numpy as np

from ..kernels.refine import box_heat_features, refined_edges

#: Heat levels, as fractions of the way from the heat threshold to a blob's
#: peak, whose bounding boxes are features.
LEVELS = (1 / 3, 2 / 3)
#: Length of a feature vector: a constant, the box of each level, the heat's
#: centroid and spread, the box's height and its distance from the middle column.
N_FEATURES = 1 + 4 * len(LEVELS) + 4 + 2
_LEVELS = np.array(LEVELS, dtype=np.float64)


def mirrored(boxes, frame_width):
    """Which boxes lie left of the middle column (and are measured mirrored)."""
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    return boxes[:, 0] + boxes[:, 2] < frame_width


def heat_features(heat, origin, boxes, threshold, frame_size):
    """Features of the heat inside each box.

    Parameters
    ----------
    heat : ndarray, shape (h, w)
        Heat over a region of the frame.
    origin : tuple of int
        ``(x0, y0)`` of that region in the frame.
    boxes : ndarray of int, shape (N, 4)
        Blob boxes in frame pixels (exclusive ``x2``/``y2``).
    threshold : float
        The heat threshold the blobs were cut at.
    frame_size : tuple of int
        ``(width, height)`` of the frame.

    Returns
    -------
    ndarray of float64, shape (N, N_FEATURES)
        Per box: 1; for each of :data:`LEVELS` the bounding box of the heat
        at or above that level (its four edges, as offsets from the box
        centre in box widths and heights); the centroid of the heat above
        the threshold (same units) and its standard deviation (in box
        widths and heights); the log of the box height in frame heights;
        the distance of the box centre from the frame's middle column in
        frame heights.  Boxes left of the middle (:func:`mirrored`) are
        measured in the mirrored frame: their x offsets change sign and
        their left and right edges swap.
    """
    boxes = np.ascontiguousarray(np.asarray(boxes, dtype=np.int64).reshape(-1, 4))
    heat = np.asarray(heat)
    if heat.dtype != np.float32 and heat.dtype != np.float64:
        heat = heat.astype(np.float64)
    out = np.empty((len(boxes), N_FEATURES))
    frame_width, frame_height = frame_size
    box_heat_features(heat, int(origin[0]), int(origin[1]), boxes, float(threshold),
                      int(frame_width), int(frame_height), _LEVELS, out)
    return out


def refine_boxes(boxes, features, weights, frame_width):
    """Boxes whose edges the linear model places.

    Parameters
    ----------
    boxes : ndarray of int, shape (N, 4)
    features : ndarray, shape (N, N_FEATURES)
        :func:`heat_features` of those boxes.
    weights : array_like, shape (4, N_FEATURES)
        Rows for x1, y1, x2, y2 (of the mirrored box, left of the middle).
    frame_width : int or ndarray of shape (N,)
        Width of the frame (of each box's frame), whose middle column
        decides the mirroring.

    Returns
    -------
    ndarray of float64, shape (N, 4)
        Unrounded, unclipped; an edge pair the model crosses is put back in
        order.
    """
    boxes = np.ascontiguousarray(np.asarray(boxes, dtype=np.int64).reshape(-1, 4))
    out = np.empty((len(boxes), 4))
    # A writable array of its own (a broadcast view is read-only: another
    # signature to compile).
    frame_widths = np.empty(len(boxes))
    frame_widths[:] = frame_width
    refined_edges(boxes, np.ascontiguousarray(features, dtype=np.float64),
                  np.ascontiguousarray(weights, dtype=np.float64), frame_widths, out)
    return out
