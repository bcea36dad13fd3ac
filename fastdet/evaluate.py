"""Detection-quality metrics: IoU, PASCAL-VOC style matching, precision, recall, AP.

Pure numpy, independent of how the detections were produced.  Boxes are
``[x1, y1, x2, y2]`` in pixels with exclusive ``x2``/``y2`` (the convention of
:class:`fastdet.detections.Detections` and of the annotation files), so a
box's area is ``(x2 - x1) * (y2 - y1)``.

Ground truth comes from an annotation file::

    {"images": {"test1.jpg": [{"box": [x1, y1, x2, y2], "label": "car",
                               "difficult": false}, ...], ...}}

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

Typical use::

    annotations = load_annotations("test_images/annotations.json")
    results = {name: (dets.xyxy, dets.score) for name, dets in detections.items()}
    report = evaluate(results, annotations)
    print(report.precision, report.recall, report.ap)
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import InputError

#: Label of a prediction matched to a non-difficult ground-truth box.
TRUE_POSITIVE = 1
#: Label of a prediction matched to nothing (background, poor overlap, duplicate).
FALSE_POSITIVE = 0
#: Label of a prediction whose best match is a difficult ground-truth box.
IGNORED = -1
#: Default share of a detection's area that must lie inside a difficult box
#: for the detection to be ignored when it matches nothing (see module doc).
DIFFICULT_COVER = 0.5


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
    boxes_a = _as_box_array(boxes_a, "boxes_a")
    boxes_b = _as_box_array(boxes_b, "boxes_b")
    area_a = _box_areas(boxes_a)
    area_b = _box_areas(boxes_b)
    # Broadcast (N, 1) against (1, M): overlap extents of every pair.
    overlap_w = (np.minimum(boxes_a[:, None, 2], boxes_b[None, :, 2])
                 - np.maximum(boxes_a[:, None, 0], boxes_b[None, :, 0]))
    overlap_h = (np.minimum(boxes_a[:, None, 3], boxes_b[None, :, 3])
                 - np.maximum(boxes_a[:, None, 1], boxes_b[None, :, 1]))
    intersection = np.clip(overlap_w, 0, None) * np.clip(overlap_h, 0, None)
    union = area_a[:, None] + area_b[None, :] - intersection
    iou = np.zeros_like(intersection)
    np.divide(intersection, union, out=iou, where=union > 0)
    return iou


def cover_matrix(boxes_a, boxes_b):
    """Share of each box of ``boxes_a`` lying inside each box of ``boxes_b``.

    Returns
    -------
    ndarray of float64, shape (N, M)
        ``intersection(a_i, b_j) / area(a_i)``; 0 where ``a_i`` has no area.
    """
    boxes_a = _as_box_array(boxes_a, "boxes_a")
    boxes_b = _as_box_array(boxes_b, "boxes_b")
    overlap_w = (np.minimum(boxes_a[:, None, 2], boxes_b[None, :, 2])
                 - np.maximum(boxes_a[:, None, 0], boxes_b[None, :, 0]))
    overlap_h = (np.minimum(boxes_a[:, None, 3], boxes_b[None, :, 3])
                 - np.maximum(boxes_a[:, None, 1], boxes_b[None, :, 1]))
    intersection = np.clip(overlap_w, 0, None) * np.clip(overlap_h, 0, None)
    area = _box_areas(boxes_a)[:, None]
    cover = np.zeros_like(intersection)
    np.divide(intersection, area, out=cover, where=area > 0)
    return cover


def _as_box_array(boxes, name):
    boxes = np.asarray(boxes, dtype=np.float64)
    if boxes.size == 0:
        return boxes.reshape(0, 4)
    if boxes.ndim != 2 or boxes.shape[1] != 4:
        raise InputError(f"{name} must have shape (N, 4), got {boxes.shape}")
    return boxes


def _box_areas(boxes):
    # Inverted boxes get zero area rather than a negative one.
    return (np.clip(boxes[:, 2] - boxes[:, 0], 0, None)
            * np.clip(boxes[:, 3] - boxes[:, 1], 0, None))


# -- annotations ------------------------------------------------------------

def load_annotations(path):
    """Read and validate an annotation file.

    Parameters
    ----------
    path : str or Path
        JSON file of the form ``{"images": {name: [object, ...]}}`` where each
        object has ``"box": [x1, y1, x2, y2]`` (numbers, ``x2 > x1``,
        ``y2 > y1``) and optionally ``"label"`` (str, default ``"car"``) and
        ``"difficult"`` (bool, default ``False``).  Other top-level keys
        (such as ``"format"``, a description) are ignored.

    Returns
    -------
    dict of str to list of dict
        Image name to its objects, each normalised to
        ``{"box": [float x4], "label": str, "difficult": bool}``.

    Raises
    ------
    InputError
        With a one-line message naming the file and the first problem: the
        file is missing, is not JSON, or does not have the structure above.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"annotation file not found: {path}")
    try:
        with open(path, encoding="utf-8") as handle:
            data = json.load(handle)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        # JSONDecodeError's message is already one line with position info.
        raise InputError(f"{path} is not valid JSON: {exc}") from None
    if not isinstance(data, dict) or not isinstance(data.get("images"), dict):
        raise InputError(f"{path} must hold a JSON object with an \"images\" object")
    annotations = {}
    for image_name, objects in data["images"].items():
        if not isinstance(objects, list):
            raise InputError(f"{path}: images[{image_name!r}] must be a list of objects")
        annotations[image_name] = [_parse_object(obj, f"{path}: images[{image_name!r}][{index}]")
                                   for index, obj in enumerate(objects)]
    return annotations


def _parse_object(obj, where):
    if not isinstance(obj, dict):
        raise InputError(f"{where} must be an object with a \"box\"")
    box = obj.get("box")
    # bool is an int subclass; a box of booleans is certainly a mistake.
    if (not isinstance(box, list) or len(box) != 4
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                       and math.isfinite(v) for v in box)):
        raise InputError(f"{where}.box must be a list of 4 finite numbers, got {box!r}")
    if not (box[2] > box[0] and box[3] > box[1]):
        raise InputError(f"{where}.box must have x2 > x1 and y2 > y1, got {box!r}")
    label = obj.get("label", "car")
    if not isinstance(label, str):
        raise InputError(f"{where}.label must be a string, got {label!r}")
    difficult = obj.get("difficult", False)
    if not isinstance(difficult, bool):
        raise InputError(f"{where}.difficult must be true or false, got {difficult!r}")
    return {"box": [float(v) for v in box], "label": label, "difficult": difficult}


def ground_truth_arrays(objects):
    """Boxes and difficult flags of one image's annotation objects.

    Parameters
    ----------
    objects : list of dict
        One image's entry of :func:`load_annotations`.

    Returns
    -------
    boxes : ndarray of float64, shape (M, 4)
    difficult : ndarray of bool, shape (M,)
    """
    boxes = np.array([obj["box"] for obj in objects], dtype=np.float64).reshape(-1, 4)
    difficult = np.array([bool(obj.get("difficult", False)) for obj in objects], dtype=bool)
    return boxes, difficult


# -- matching ---------------------------------------------------------------

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
    """

    labels: np.ndarray
    scores: np.ndarray
    ious: np.ndarray
    matched_gt: np.ndarray
    n_positives: int
    gt_found: np.ndarray

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
    pred_boxes = _as_box_array(pred_boxes, "pred_boxes")
    pred_scores = np.asarray(pred_scores, dtype=np.float64).reshape(-1)
    gt_boxes = _as_box_array(gt_boxes, "gt_boxes")
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
    return ImageMatch(labels=labels, scores=pred_scores, ious=matched_iou, matched_gt=matched_gt,
                      n_positives=int(np.count_nonzero(~gt_difficult)), gt_found=gt_found)


# -- pooled metrics ---------------------------------------------------------

def average_precision(labels, scores, n_positives):
    """PASCAL-VOC (2010+) all-point interpolated average precision.

    The ranked list is every non-ignored prediction sorted by descending
    score (stable, so ties keep their given order).  Precision is made
    monotone by taking, at each rank, the best precision at that or any
    later rank; AP is the area under that envelope as a step function of
    recall.

    Parameters
    ----------
    labels : array_like of int, shape (N,)
        ``TRUE_POSITIVE``, ``FALSE_POSITIVE`` or ``IGNORED`` per prediction.
    scores : array_like of float, shape (N,)
    n_positives : int
        Number of non-difficult ground-truth boxes.

    Returns
    -------
    float
        AP in [0, 1]; 0 when ``n_positives`` is 0 (undefined there, and 0
        never flatters a detector).
    """
    labels = np.asarray(labels).reshape(-1)
    scores = np.asarray(scores, dtype=np.float64).reshape(-1)
    if n_positives <= 0:
        return 0.0
    ranked = labels != IGNORED
    labels, scores = labels[ranked], scores[ranked]
    order = np.argsort(-scores, kind="stable")
    is_tp = labels[order] == TRUE_POSITIVE
    cumulative_tp = np.cumsum(is_tp)
    cumulative_fp = np.cumsum(~is_tp)
    recall = np.concatenate([[0.0], cumulative_tp / n_positives, [1.0]])
    precision = np.concatenate(
        [[0.0], cumulative_tp / np.maximum(cumulative_tp + cumulative_fp, 1), [0.0]])
    # Envelope: right-to-left running maximum.
    precision = np.maximum.accumulate(precision[::-1])[::-1]
    steps = np.flatnonzero(recall[1:] != recall[:-1])
    return float(np.sum((recall[steps + 1] - recall[steps]) * precision[steps + 1]))


@dataclass
class EvalReport:
    """Detection quality over a set of images.

    Attributes
    ----------
    precision : float
        ``tp / (tp + fp)`` over all non-ignored predictions (no score cut).
    recall : float
        ``tp / n_gt``.
    ap : float
        All-point interpolated average precision of the predictions of all
        images pooled and ranked by score (:func:`average_precision`).
    mean_iou : float
        Mean IoU of the true-positive matches.
    tp, fp, fn : int
        True positives, false positives, missed non-difficult boxes.
    n_gt : int
        Non-difficult ground-truth boxes.
    ignored : int
        Predictions matched to difficult boxes (counted nowhere else).
    iou_threshold : float
    difficult_cover : float or None
        The coverage rule used for difficult boxes (``None``: plain VOC).
    per_image : dict of str to ImageMatch

    Notes
    -----
    Ratios without a denominator are defined so that the report stays finite
    (and JSON-friendly):

    * no predictions: ``precision = 1.0`` (no wrong claims were made);
    * no non-difficult ground truth: ``recall = 1.0`` (nothing was missed)
      and ``ap = 0.0`` (AP is undefined; 0 never flatters);
    * no true positives: ``mean_iou = 0.0``.
    """

    precision: float
    recall: float
    ap: float
    mean_iou: float
    tp: int
    fp: int
    fn: int
    n_gt: int
    ignored: int
    iou_threshold: float
    difficult_cover: float | None = DIFFICULT_COVER
    per_image: dict = field(default_factory=dict, repr=False)

    def to_dict(self, per_image=True):
        """JSON-ready summary, optionally with per-image counts.

        Parameters
        ----------
        per_image : bool
            Include ``{"images": {name: {"tp", "fp", "fn", "ignored"}}}``.

        Returns
        -------
        dict
        """
        summary = {name: getattr(self, name) for name in
                   ("precision", "recall", "ap", "mean_iou", "tp", "fp", "fn", "n_gt",
                    "ignored", "iou_threshold", "difficult_cover")}
        if per_image:
            summary["images"] = {name: {"tp": match.tp, "fp": match.fp, "fn": match.fn,
                                        "ignored": match.ignored}
                                 for name, match in self.per_image.items()}
        return summary


def evaluate(results, annotations, iou_threshold=0.5, difficult_cover=DIFFICULT_COVER):
    """Match predictions to ground truth on every image and pool the metrics.

    Parameters
    ----------
    results : dict
        Image name to ``(boxes, scores)``: boxes ``(N, 4)`` ``[x1, y1, x2,
        y2]`` (``x2``/``y2`` exclusive) and scores ``(N,)``.  A
        :class:`~fastdet.detections.Detections` is accepted in place of the
        tuple.  Annotated images missing from ``results`` count as having no
        predictions.
    annotations : dict
        Image name to annotation objects, as returned by
        :func:`load_annotations`.
    iou_threshold : float
        Minimum IoU (inclusive) for a prediction to match a box.
    difficult_cover : float or None
        Coverage rule for difficult boxes (see :func:`match_image`); ``None``
        for the plain VOC rule.

    Returns
    -------
    EvalReport
        See its Notes for the values used when there are no predictions or
        no ground truth.

    Raises
    ------
    InputError
        If ``results`` names images that have no annotations (they cannot be
        scored, and silently dropping them would flatter precision), or if
        ``difficult_cover`` is not in (0, 1].
    """
    if difficult_cover is not None and not 0 < difficult_cover <= 1:
        # At 0 every false positive beside a difficult box would be ignored.
        raise InputError(f"difficult_cover must be in (0, 1] or None, got {difficult_cover!r}")
    unannotated = sorted(set(results) - set(annotations))
    if unannotated:
        shown = ", ".join(unannotated[:5]) + (", ..." if len(unannotated) > 5 else "")
        raise InputError(f"{len(unannotated)} image(s) have results but no annotations: {shown}")
    per_image = {}
    for image_name, objects in annotations.items():
        boxes, scores = _boxes_and_scores(results.get(image_name))
        gt_boxes, gt_difficult = ground_truth_arrays(objects)
        per_image[image_name] = match_image(boxes, scores, gt_boxes, gt_difficult, iou_threshold,
                                            difficult_cover)

    matches = list(per_image.values())
    labels = np.concatenate([m.labels for m in matches] or [np.zeros(0, np.int8)])
    scores = np.concatenate([m.scores for m in matches] or [np.zeros(0)])
    ious = np.concatenate([m.ious for m in matches] or [np.zeros(0)])
    tp = int(np.count_nonzero(labels == TRUE_POSITIVE))
    fp = int(np.count_nonzero(labels == FALSE_POSITIVE))
    n_gt = sum(m.n_positives for m in matches)
    return EvalReport(
        precision=tp / (tp + fp) if tp + fp else 1.0,
        recall=tp / n_gt if n_gt else 1.0,
        ap=average_precision(labels, scores, n_gt),
        mean_iou=float(ious[labels == TRUE_POSITIVE].mean()) if tp else 0.0,
        tp=tp, fp=fp, fn=n_gt - tp, n_gt=n_gt,
        ignored=int(np.count_nonzero(labels == IGNORED)),
        iou_threshold=float(iou_threshold),
        difficult_cover=None if difficult_cover is None else float(difficult_cover),
        per_image=per_image,
    )


def _boxes_and_scores(result):
    if result is None:
        return np.zeros((0, 4)), np.zeros(0)
    if hasattr(result, "xyxy") and hasattr(result, "score"):
        return result.xyxy, result.score
    try:
        boxes, scores = result
    except (TypeError, ValueError):
        raise InputError("each result must be a (boxes, scores) pair or a Detections") from None
    return boxes, scores
