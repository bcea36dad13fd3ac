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

#: Heat levels, as fractions of the way from the heat threshold to a blob's
#: peak, whose bounding boxes are features.
LEVELS = (1 / 3, 2 / 3)
#: Length of a feature vector: a constant, the box of each level, the heat's
#: centroid and spread, the box's height and its distance from the middle column.
N_FEATURES = 1 + 4 * len(LEVELS) + 4 + 2


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
    out = np.zeros((len(boxes), N_FEATURES))
    out[:, 0] = 1.0
    frame_width, frame_height = frame_size
    geometry = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    out[:, -2] = np.log(np.maximum(geometry[:, 3] - geometry[:, 1], 1) / frame_height)
    out[:, -1] = np.abs((geometry[:, 0] + geometry[:, 2]) / 2 - frame_width / 2) / frame_height
    flip = mirrored(geometry, frame_width)
    ox, oy = origin
    for row, (x1, y1, x2, y2) in enumerate(np.asarray(boxes, dtype=np.int64)):
        width, height = max(x2 - x1, 1), max(y2 - y1, 1)
        cx, cy = (x1 + x2) / 2, (y1 + y2) / 2
        a1, b1 = max(x1 - ox, 0), max(y1 - oy, 0)
        a2, b2 = min(x2 - ox, heat.shape[1]), min(y2 - oy, heat.shape[0])
        mass = np.zeros((0, 0))
        if a2 > a1 and b2 > b1:
            mass = np.maximum(heat[b1:b2, a1:a2].astype(np.float64) - threshold, 0.0)
        total = mass.sum()
        if total <= 0:
            # No heat inside (a box moved off its blob): the features of a
            # flat blob filling its box.
            out[row, 1:-2] = [-0.5, -0.5, 0.5, 0.5] * len(LEVELS) + [0, 0, 0.29, 0.29]
            continue
        xs = (np.arange(a1, a2) + ox + 0.5 - cx) / width
        ys = (np.arange(b1, b2) + oy + 0.5 - cy) / height
        columns, rows = mass.sum(axis=0), mass.sum(axis=1)
        peak = mass.max()
        col = 1
        for level in LEVELS:
            above = mass >= level * peak
            cols_in = np.flatnonzero(above.any(axis=0))
            rows_in = np.flatnonzero(above.any(axis=1))
            left, right = xs[cols_in[0]] - 0.5 / width, xs[cols_in[-1]] + 0.5 / width
            if flip[row]:
                left, right = -right, -left
            out[row, col:col + 4] = (left, ys[rows_in[0]] - 0.5 / height, right,
                                     ys[rows_in[-1]] + 0.5 / height)
            col += 4
        mx = columns @ xs / total
        my = rows @ ys / total
        out[row, col:col + 4] = (-mx if flip[row] else mx, my,
                                 np.sqrt(columns @ (xs - mx) ** 2 / total),
                                 np.sqrt(rows @ (ys - my) ** 2 / total))
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
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    offsets = features @ np.asarray(weights, dtype=np.float64).T
    flip = mirrored(boxes, frame_width)
    offsets[flip] = np.stack([-offsets[flip, 2], offsets[flip, 1], -offsets[flip, 0],
                              offsets[flip, 3]], axis=1)
    width = boxes[:, 2] - boxes[:, 0]
    height = boxes[:, 3] - boxes[:, 1]
    cx = (boxes[:, 0] + boxes[:, 2]) / 2
    cy = (boxes[:, 1] + boxes[:, 3]) / 2
    out = np.stack([cx + offsets[:, 0] * width, cy + offsets[:, 1] * height,
                    cx + offsets[:, 2] * width, cy + offsets[:, 3] * height], axis=1)
    return np.concatenate([np.minimum(out[:, :2], out[:, 2:]), np.maximum(out[:, :2], out[:, 2:])],
                          axis=1)
