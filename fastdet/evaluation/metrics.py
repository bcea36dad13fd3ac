"""Pooled detection-quality metrics: precision, recall, AP and IoU over a set of images.

Pure numpy, independent of how the detections were produced.

Typical use::

    annotations = load_annotations("test_images/annotations.json")
    results = {name: (dets.xyxy, dets.score) for name, dets in detections.items()}
    report = evaluate(results, annotations)
    print(report.precision, report.recall, report.ap)
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from .annotations import ground_truth_arrays
from .error_kinds import FALSE_BOX_KINDS, LOCALISATION
from .matching import DIFFICULT_COVER, FALSE_POSITIVE, IGNORED, TRUE_POSITIVE, match_image


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
    iou_p10 : float
        Their 10th percentile (linear interpolation): the mean hides the few
        poorly placed boxes a user sees.
    tp, fp, fn : int
        True positives, false positives, missed non-difficult boxes.
    n_gt : int
        Non-difficult ground-truth boxes.
    ignored : int
        Predictions matched to difficult boxes (counted nowhere else).
    iou_threshold : float
    difficult_cover : float or None
        The coverage rule used for difficult boxes (``None``: plain VOC).
    errors : dict
        What the false positives and misses are (:func:`error_summary`).
    per_image : dict of str to ImageMatch

    Notes
    -----
    Ratios without a denominator are given values so that the attributes
    stay finite numbers a search can rank (``fastdet tune``):

    * no predictions: ``precision = 1.0`` (no wrong claims were made);
    * no non-difficult ground truth: ``recall = 1.0`` (nothing was missed)
      and ``ap = 0.0`` (AP is undefined; 0 never flatters);
    * no true positives: ``mean_iou = iou_p10 = 0.0``.

    :meth:`undefined` names them; :meth:`to_dict` gives them as ``None``
    and ``fastdet eval`` prints them as ``n/a``, so a report of frames
    without vehicles does not read as a perfect recall and a zero AP.
    """

    precision: float
    recall: float
    ap: float
    mean_iou: float
    iou_p10: float
    tp: int
    fp: int
    fn: int
    n_gt: int
    ignored: int
    iou_threshold: float
    difficult_cover: float | None = DIFFICULT_COVER
    errors: dict = field(default_factory=dict)
    per_image: dict = field(default_factory=dict, repr=False)

    def undefined(self):
        """The figures that have no denominator here (see Notes), as a set of names.

        Returns
        -------
        set of str
            ``"precision"`` without predictions, ``"recall"`` and ``"ap"``
            without non-difficult ground truth, ``"mean_iou"`` and
            ``"iou_p10"`` without true positives.
        """
        names = set()
        if self.tp + self.fp == 0:
            names.add("precision")
        if self.n_gt == 0:
            names.update(("recall", "ap"))
        if self.tp == 0:
            names.update(("mean_iou", "iou_p10"))
        return names

    def to_dict(self, per_image=True):
        """JSON-ready summary (``None`` for each of :meth:`undefined`), optionally with per-image counts.

        Parameters
        ----------
        per_image : bool
            Include ``{"images": {name: {"tp", "fp", "fn", "ignored",
            "false_positives", "misses"}}}``, the last two as
            :meth:`~.matching.ImageMatch.errors` gives them.

        Returns
        -------
        dict
        """
        undefined = self.undefined()
        summary = {name: None if name in undefined else getattr(self, name) for name in
                   ("precision", "recall", "ap", "mean_iou", "iou_p10", "tp", "fp", "fn", "n_gt",
                    "ignored", "iou_threshold", "difficult_cover", "errors")}
        if per_image:
            summary["images"] = {name: {"tp": match.tp, "fp": match.fp, "fn": match.fn,
                                        "ignored": match.ignored, **match.errors()}
                                 for name, match in self.per_image.items()}
        return summary


def evaluate(results, annotations, iou_threshold=0.5, difficult_cover=DIFFICULT_COVER):
    """Match predictions to ground truth on every image and pool the metrics.

    Parameters
    ----------
    results : dict
        Image name to ``(boxes, scores)``: boxes ``(N, 4)`` ``[x1, y1, x2,
        y2]`` (``x2``/``y2`` exclusive) and scores ``(N,)``.  A
        :class:`~fastdet.detector.detections.Detections` is accepted in place of the
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
        ``iou_threshold`` or ``difficult_cover`` is not in (0, 1].
    """
    if not 0 < iou_threshold <= 1:       # NaN too
        raise InputError(f"the match IoU (--iou) must be in (0, 1], got {iou_threshold}")
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
    matched = ious[labels == TRUE_POSITIVE]
    ap = average_precision(labels, scores, n_gt)
    return EvalReport(
        precision=tp / (tp + fp) if tp + fp else 1.0,
        recall=tp / n_gt if n_gt else 1.0,
        ap=ap,
        mean_iou=float(matched.mean()) if tp else 0.0,
        iou_p10=float(np.percentile(matched, 10)) if tp else 0.0,
        tp=tp, fp=fp, fn=n_gt - tp, n_gt=n_gt,
        ignored=int(np.count_nonzero(labels == IGNORED)),
        iou_threshold=float(iou_threshold),
        difficult_cover=None if difficult_cover is None else float(difficult_cover),
        errors=error_summary(matches, ap),
        per_image=per_image,
    )


def error_summary(matches, ap):
    """The false positives and misses of several images by kind, and what fixing each kind gains.

    Kinds as :mod:`.error_kinds` defines them.  The gain of a kind is TIDE's dAP:
    the AP once an oracle fixes every error of that kind and nothing else,
    minus ``ap``.  Duplicates, boxes on difficult vehicles and boxes on
    background are fixed by dropping them; a localisation error becomes a
    true positive of its vehicle when no box found that vehicle (the
    highest-scoring such box, in ranking order), and is dropped otherwise;
    misses without a false positive near them are fixed by not requiring
    those vehicles.

    Parameters
    ----------
    matches : list of ImageMatch
    ap : float
        AP of the predictions as they are (:func:`average_precision`).

    Returns
    -------
    dict
        ``{"false_positives": {kind: count}, "misses": {"near": n, "missed":
        n}, "ap_gain": {kind: gain, ..., "missed": gain}}``.
    """
    labels = np.concatenate([m.labels for m in matches] or [np.zeros(0, np.int8)])
    scores = np.concatenate([m.scores for m in matches] or [np.zeros(0)])
    kinds = np.concatenate([m.error_kinds for m in matches] or [np.zeros(0, np.int8)])
    # A vehicle is (image, box) once the images are pooled.
    vehicles = [(image, int(box)) for image, m in enumerate(matches) for box in m.error_vehicles]
    n_gt = sum(m.n_positives for m in matches)
    near = sum(int(np.count_nonzero(m.near_misses)) for m in matches)
    missed = sum(m.fn for m in matches) - near
    counts = {name: int(np.count_nonzero(kinds == code))
              for code, name in enumerate(FALSE_BOX_KINDS)}
    gains = {}
    for code, name in enumerate(FALSE_BOX_KINDS):
        fixed = labels.copy()
        if code == LOCALISATION:
            taken = set()
            for p in np.argsort(-scores, kind="stable"):
                if kinds[p] != LOCALISATION:
                    continue
                found = _vehicle_found(matches, vehicles[p])
                fixed[p] = IGNORED if found or vehicles[p] in taken else TRUE_POSITIVE
                taken.add(vehicles[p])
        else:
            fixed[kinds == code] = IGNORED
        gains[name] = average_precision(fixed, scores, n_gt) - ap
    gains["missed"] = average_precision(labels, scores, n_gt - missed) - ap if missed else 0.0
    return {"false_positives": counts, "misses": {"near": near, "missed": missed},
            "ap_gain": gains}


def _vehicle_found(matches, vehicle):
    """Whether a true positive found ``vehicle``, an ``(image index, box index)`` pair."""
    image, box = vehicle
    return bool(matches[image].gt_found[box])


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
