"""Fitting the box refinement (:mod:`fastdet.detector.refine`) on annotated frames.

Every blob the detector finds on an annotated frame that overlaps a
non-difficult vehicle (IoU at least ``MATCH_IOU`` after the shape
correction) is one sample: its heat features, and where the vehicle's edges
lie relative to the blob's box.  A ridge regression per edge maps one to
the other; the constant term is not penalised, so with few samples the fit
falls back to a constant correction of the box (what the shape correction
does), and the other terms only count as far as the samples support them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..detector.geometry import iou_matrix
from ..detector.refine import heat_features, mirrored, refine_boxes
from ..evaluation.annotations import ground_truth_arrays

#: Least IoU of a blob's shape-corrected box with a vehicle for the pair to be a sample.
MATCH_IOU = 0.3
#: Ridge penalty on the non-constant weights (features are in box units, about 0.1-1).
RIDGE = 1.0


@dataclass
class RefinementSamples:
    """Blob boxes, their heat features, their vehicles' boxes and their frames' widths."""

    boxes: np.ndarray
    features: np.ndarray
    truth: np.ndarray
    frame_widths: np.ndarray

    def __len__(self):
        return len(self.boxes)


def refinement_samples(box_finder, blobs, annotations):
    """Pair blobs with the vehicles they found.

    Parameters
    ----------
    box_finder : BoxFinder
        Its config gives the heat threshold and the shape correction used
        for matching.
    blobs : dict
        Frame key to ``(boxes, heat, origin, frame_size)``: blob boxes from
        :meth:`BoxFinder.heat_components` and the heat they came from.
    annotations : dict
        Frame key to annotation objects.

    Returns
    -------
    RefinementSamples
    """
    boxes, features, truth, widths = [], [], [], []
    for key, (blob_boxes, heat, origin, size) in blobs.items():
        gt, difficult = ground_truth_arrays(annotations[key])
        gt = gt[~difficult]
        if not len(blob_boxes) or not len(gt):
            continue
        iou = iou_matrix(box_finder.reshape_boxes(blob_boxes, size), gt)
        best = iou.argmax(axis=1)
        matched = iou[np.arange(len(best)), best] >= MATCH_IOU
        if matched.any():
            boxes.append(blob_boxes[matched])
            features.append(heat_features(heat, origin, blob_boxes[matched],
                                          box_finder.config.heat.threshold, size))
            truth.append(gt[best[matched]])
            widths.append(np.full(int(matched.sum()), float(size[0])))
    if not boxes:
        return RefinementSamples(np.zeros((0, 4)), np.zeros((0, 0)), np.zeros((0, 4)),
                                 np.zeros(0))
    return RefinementSamples(np.concatenate(boxes).astype(np.float64), np.concatenate(features),
                             np.concatenate(truth), np.concatenate(widths))


def fit_refinement(samples, ridge=RIDGE):
    """Ridge-regression weights of the four edges on the heat features.

    Returns
    -------
    ndarray of float64, shape (4, N_FEATURES)
        ``[boxes] refine`` (``()`` without samples).
    """
    if len(samples) == 0:
        return ()
    boxes, features = samples.boxes, samples.features
    width = boxes[:, 2] - boxes[:, 0]
    height = boxes[:, 3] - boxes[:, 1]
    cx = (boxes[:, 0] + boxes[:, 2]) / 2
    cy = (boxes[:, 1] + boxes[:, 3]) / 2
    truth = samples.truth
    targets = np.stack([(truth[:, 0] - cx) / width, (truth[:, 1] - cy) / height,
                        (truth[:, 2] - cx) / width, (truth[:, 3] - cy) / height], axis=1)
    # Boxes left of the middle are modelled mirrored (see fastdet.detector.refine).
    flip = mirrored(boxes, samples.frame_widths)
    targets[flip] = np.stack([-targets[flip, 2], targets[flip, 1], -targets[flip, 0],
                              targets[flip, 3]], axis=1)
    penalty = np.full(features.shape[1], float(ridge))
    penalty[0] = 0.0
    weights = np.linalg.solve(features.T @ features + np.diag(penalty), features.T @ targets)
    return weights.T


def refined_ious(samples, weights):
    """IoU of each sample's refined box (or, without weights, its blob box) with its vehicle."""
    boxes = samples.boxes if not len(weights) else refine_boxes(
        samples.boxes, samples.features, weights, samples.frame_widths)
    return np.array([iou_matrix(b[None], t[None])[0, 0] for b, t in zip(boxes, samples.truth)])
