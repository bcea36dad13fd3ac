"""PASCAL-VOC style matching of one image's detections to its ground truth.

Boxes marked ``difficult`` (far away, heavily occluded, ...) are neither
required nor penalised: missing one is not an error, and a detection on one
is ignored (neither a true nor a false positive).  "On one" is the PASCAL-VOC
rule -- IoU >= the match threshold with the difficult box -- extended by a
coverage rule: a detection that matches no vehicle but has at least
``difficult_cover`` (default half) of its own area inside one difficult box
is ignored too.  VOC alone calls a loose or partial box on a difficult car
(a distant truck's box that also takes in the barrier below it) a false
positive, i.e. penalises the detector for a car it was told it need not
find; the coverage rule (the "ignore region" convention of COCO crowd boxes
and the Caltech pedestrian benchmark) does not, while a detection that lies
mostly on background stays a false positive.  ``difficult_cover=None`` gives
the plain VOC rule.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..detector.geometry import as_box_array, cover_matrix, iou_matrix
from ..errors import InputError
from .error_kinds import FALSE_BOX_KINDS, classify_errors

#: Label of a prediction matched to a non-difficult ground-truth box.
TRUE_POSITIVE = 1
#: Label of a prediction matched to nothing (background, poor overlap, duplicate).
FALSE_POSITIVE = 0
#: Label of a prediction whose best match is a difficult ground-truth box.
IGNORED = -1
#: Default share of a detection's area that must lie inside a difficult box
#: for the detection to be ignored when it matches nothing (see module doc).
DIFFICULT_COVER = 0.5


@dataclass
class ImageMatch:
    """How one image's predictions matched its ground truth.

    Arrays indexed by prediction are in the order the predictions were given.

    Attributes
    ----------
    labels : ndarray of int8, shape (N,)
        ``TRUE_POSITIVE`` (1), ``FALSE_POSITIVE`` (0) or ``IGNORED`` (-1).
    scores : ndarray of float64, shape (N,)
        The predictions' scores.
    ious : ndarray of float64, shape (N,)
        IoU with the matched ground-truth box for true positives and ignored
        predictions; for false positives the highest IoU with any
        ground-truth box (0 without any), which tells poorly localised boxes
        and duplicates from detections on background.
    matched_gt : ndarray of int64, shape (N,)
        Index of the matched ground-truth box, -1 for false positives.
    n_positives : int
        Number of non-difficult ground-truth boxes (the ones recall counts).
    gt_found : ndarray of bool, shape (M,)
        Which ground-truth boxes a true positive matched (always ``False``
        for difficult ones).
    error_kinds : ndarray of int8, shape (N,)
        Each false positive's kind, an index into
        :data:`~.error_kinds.FALSE_BOX_KINDS` (duplicate, localisation, difficult,
        background); :data:`~.error_kinds.NOT_AN_ERROR` for the other predictions.
    error_vehicles : ndarray of int64, shape (N,)
        The ground-truth box a duplicate or a localisation error lies on, else -1.
    near_misses : ndarray of bool, shape (M,)
        Missed non-difficult boxes that a false positive overlaps at IoU
        :data:`~.error_kinds.NEAR_IOU` or more.
    pred_boxes : ndarray of float64, shape (N, 4)
        The predictions' boxes.
    gt_boxes : ndarray of float64, shape (M, 4)
        The ground-truth boxes.
    gt_difficult : ndarray of bool, shape (M,)
        Which of them are difficult.
    """

    labels: np.ndarray
    scores: np.ndarray
    ious: np.ndarray
    matched_gt: np.ndarray
    n_positives: int
    gt_found: np.ndarray
    error_kinds: np.ndarray
    error_vehicles: np.ndarray
    near_misses: np.ndarray
    pred_boxes: np.ndarray
    gt_boxes: np.ndarray
    gt_difficult: np.ndarray

    @property
    def tp(self):
        """Number of true positives."""
        return int(np.count_nonzero(self.labels == TRUE_POSITIVE))

    @property
    def fp(self):
        """Number of false positives."""
        return int(np.count_nonzero(self.labels == FALSE_POSITIVE))

    @property
    def fn(self):
        """Number of non-difficult ground-truth boxes no prediction found."""
        return self.n_positives - self.tp

    @property
    def ignored(self):
        """Number of predictions on difficult boxes."""
        return int(np.count_nonzero(self.labels == IGNORED))

    def verdicts(self):
        """One word per prediction, in the order given: ``"match"``, ``"ignored"`` (on a
        difficult vehicle, by the rules) or the kind of false positive."""
        return ["match" if label == TRUE_POSITIVE else "ignored" if label == IGNORED
                else FALSE_BOX_KINDS[kind] for label, kind in zip(self.labels, self.error_kinds)]

    def errors(self):
        """The false positives and misses, JSON-ready.

        Returns
        -------
        dict
            ``{"false_positives": [{"box", "score", "kind"}, ...], "misses":
            [{"box", "near"}, ...]}``, boxes as lists of numbers, false
            positives in the order the predictions were given.
        """
        false = [{"box": _numbers(self.pred_boxes[p]), "score": float(self.scores[p]),
                  "kind": FALSE_BOX_KINDS[self.error_kinds[p]]}
                 for p in np.flatnonzero(self.labels == FALSE_POSITIVE)]
        misses = [{"box": _numbers(self.gt_boxes[g]), "near": bool(self.near_misses[g])}
                  for g in np.flatnonzero(~self.gt_found & ~self.gt_difficult)]
        return {"false_positives": false, "misses": misses}


def _numbers(box):
    """A box as JSON numbers: integers where the coordinates are whole."""
    return [int(v) if float(v).is_integer() else float(v) for v in box]


def match_image(pred_boxes, pred_scores, gt_boxes, gt_difficult=None, iou_threshold=0.5,
                difficult_cover=DIFFICULT_COVER):
    """Match one image's predictions to its ground truth, PASCAL-VOC style.

    Predictions are visited in descending score order (ties keep their given
    order).  Each one looks for its best ground-truth candidate: the
    not-yet-matched non-difficult boxes plus every difficult box (a difficult
    box may absorb any number of predictions, as in VOC).  If the best
    candidate's IoU is at least ``iou_threshold``, the prediction is a true
    positive and consumes that box when it is non-difficult, or is ignored
    when it is difficult; otherwise it is a false positive.  So a second
    detection of an already found vehicle is a false positive.  On equal
    IoU a non-difficult box is preferred, then the lower index.

    Then the coverage rule: a prediction left a false positive is ignored
    instead when at least ``difficult_cover`` of its area lies inside one
    difficult box (it is then matched to the difficult box covering most of
    it).  True positives are decided first, so a detection that finds a
    normal vehicle is never ignored.

    Parameters
    ----------
    pred_boxes : array_like, shape (N, 4)
        Predicted ``[x1, y1, x2, y2]`` boxes, ``x2``/``y2`` exclusive.
    pred_scores : array_like, shape (N,)
        Their confidences; higher is more confident.
    gt_boxes : array_like, shape (M, 4)
        Ground-truth boxes.
    gt_difficult : array_like of bool, shape (M,), optional
        Which ground-truth boxes are difficult; none by default.
    iou_threshold : float
        Minimum IoU (inclusive) for a match.
    difficult_cover : float or None
        Share of its own area (inclusive) a non-matching prediction must have
        inside a difficult box to be ignored; ``None`` for the plain VOC rule.

    Returns
    -------
    ImageMatch
    """
    pred_boxes = as_box_array(pred_boxes, "pred_boxes")
    pred_scores = np.asarray(pred_scores, dtype=np.float64).reshape(-1)
    gt_boxes = as_box_array(gt_boxes, "gt_boxes")
    n_pred, n_gt = len(pred_boxes), len(gt_boxes)
    if pred_scores.shape[0] != n_pred:
        raise InputError(f"{n_pred} predicted boxes but {pred_scores.shape[0]} scores")
    if gt_difficult is None:
        gt_difficult = np.zeros(n_gt, dtype=bool)
    gt_difficult = np.asarray(gt_difficult, dtype=bool).reshape(-1)
    if gt_difficult.shape[0] != n_gt:
        raise InputError(f"{n_gt} ground-truth boxes but {gt_difficult.shape[0]} difficult flags")

    iou = iou_matrix(pred_boxes, gt_boxes)
    labels = np.full(n_pred, FALSE_POSITIVE, dtype=np.int8)
    matched_iou = iou.max(axis=1) if n_gt else np.zeros(n_pred)
    matched_gt = np.full(n_pred, -1, dtype=np.int64)
    gt_found = np.zeros(n_gt, dtype=bool)
    # Column order for argmax: non-difficult boxes first, so that an IoU tie
    # between a difficult and a non-difficult box resolves to the latter.
    column_order = np.argsort(gt_difficult, kind="stable")
    for p in np.argsort(-pred_scores, kind="stable"):
        available = gt_difficult | ~gt_found
        candidate_iou = np.where(available, iou[p], -1.0)[column_order]
        if candidate_iou.size == 0:
            continue
        best = column_order[int(np.argmax(candidate_iou))]
        if not available[best] or iou[p, best] < iou_threshold:
            continue  # stays a false positive, with its best IoU for diagnostics
        matched_gt[p] = best
        matched_iou[p] = iou[p, best]
        if gt_difficult[best]:
            labels[p] = IGNORED
        else:
            labels[p] = TRUE_POSITIVE
            gt_found[best] = True
    if difficult_cover is not None and n_pred and gt_difficult.any():
        hard = np.flatnonzero(gt_difficult)
        cover = cover_matrix(pred_boxes, gt_boxes[hard])
        best_hard = hard[np.argmax(cover, axis=1)]
        ignore = (labels == FALSE_POSITIVE) & (cover.max(axis=1) >= difficult_cover)
        labels[ignore] = IGNORED
        matched_gt[ignore] = best_hard[ignore]
        matched_iou[ignore] = iou[ignore, best_hard[ignore]]
    kinds, vehicles, near_misses = classify_errors(iou, labels == FALSE_POSITIVE, gt_found,
                                                   gt_difficult, iou_threshold)
    return ImageMatch(labels=labels, scores=pred_scores, ious=matched_iou, matched_gt=matched_gt,
                      n_positives=int(np.count_nonzero(~gt_difficult)), gt_found=gt_found,
                      error_kinds=kinds, error_vehicles=vehicles, near_misses=near_misses,
                      pred_boxes=pred_boxes, gt_boxes=gt_boxes, gt_difficult=gt_difficult)
