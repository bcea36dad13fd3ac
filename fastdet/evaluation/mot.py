"""Tracking quality the standard way: MOTA, IDF1, ID switches and fragmentations.

The metrics are py-motmetrics' (``pip install 'fastdet[eval]'``; imported at
once here, so a missing extra fails with
:class:`~fastdet.errors.MissingExtraError`).  Each annotated frame is one
accumulator event: its non-difficult vehicles (with their ``id``) against the
tracker's boxes (with their track ids), a pair matching when their IoU is at
least ``iou_threshold`` (0.5, MOTChallenge's rule).

Difficult vehicles are neither required nor penalised, as in detection
(:mod:`fastdet.evaluation.matching`): a hypothesis that detection matching
ignores (it lies on a difficult vehicle) is removed from the frame before the
frame is accumulated, the way MOTChallenge removes boxes on its distractor
classes.

The IoU distances are computed here (:func:`~fastdet.detector.geometry.iou_matrix`,
boxes with exclusive ``x2``/``y2``): py-motmetrics 1.4's own ``iou_matrix``
calls ``np.asfarray``, which NumPy 2 removed, and takes ``(x, y, w, h)``
boxes anyway.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..detector.geometry import as_box_array, iou_matrix
from ..errors import InputError, MissingExtraError
from .annotations import frame_number, ground_truth_arrays
from .matching import DIFFICULT_COVER, IGNORED, match_image

try:
    import motmetrics
except ImportError as exc:
    raise MissingExtraError("py-motmetrics is needed for tracking metrics: "
                            "pip install 'fastdet[eval]'") from exc

#: The py-motmetrics metrics reported, by their names there.
METRICS = ("mota", "motp", "idf1", "num_switches", "num_fragmentations", "num_false_positives",
           "num_misses", "num_objects", "num_unique_objects", "mostly_tracked", "mostly_lost")


@dataclass
class TrackingReport:
    """Tracking quality over the annotated frames of one video.

    Attributes
    ----------
    mota : float
        Multiple-object tracking accuracy: ``1 - (misses + false positives
        + ID switches) / vehicles``.
    motp : float
        Mean IoU of the matched pairs (py-motmetrics reports the mean
        distance ``1 - IoU``; this is its complement); NaN without a
        matched pair, as MOTA without vehicles.
    idf1 : float
        F1 score of identity-preserving matches over the whole video.
    id_switches, fragmentations : int
        Times a vehicle's matched track id changed; times its tracked
        stretch was interrupted.
    false_positives, misses, objects : int
        Over all annotated frames (objects: non-difficult vehicle boxes).
    vehicles : int
        Distinct non-difficult vehicle ids.
    mostly_tracked, mostly_lost : int
        Vehicles tracked in at least 80 % / at most 20 % of their frames.
    frames : int
        Annotated frames evaluated.
    """

    mota: float
    motp: float
    idf1: float
    id_switches: int
    fragmentations: int
    false_positives: int
    misses: int
    objects: int
    vehicles: int
    mostly_tracked: int
    mostly_lost: int
    frames: int

    def to_dict(self):
        """JSON-ready figures (``None`` for a ratio without a denominator, e.g. MOTA
        over frames without vehicles)."""
        return {name: None if isinstance(value, float) and not math.isfinite(value) else value
                for name, value in self.__dict__.items()}


def tracking_metrics(tracks, annotations, iou_threshold=0.5, difficult_cover=DIFFICULT_COVER):
    """MOT metrics of tracked boxes against annotations with identities.

    Parameters
    ----------
    tracks : dict
        Frame name (as in the annotations) to ``(boxes, track_ids, scores)``:
        boxes ``(N, 4)`` ``[x1, y1, x2, y2]`` with exclusive ``x2``/``y2``,
        integer ids ``(N,)``, scores ``(N,)`` (they only order the matching
        that decides which boxes lie on difficult vehicles).  Annotated
        frames missing here count as frames without boxes.
    annotations : dict
        Frame name to objects (:func:`~.annotations.load_annotations`); every
        non-difficult object needs an ``id``.  Frames are taken in the order
        of their frame index (``frame<N>``), else of their names.
    iou_threshold : float
        Least IoU of a match.
    difficult_cover : float or None
        The coverage rule for boxes on difficult vehicles (see
        :func:`~.matching.match_image`).

    Returns
    -------
    TrackingReport

    Raises
    ------
    InputError
        When a non-difficult vehicle has no ``id``, or ``tracks`` names a
        frame that is not annotated.
    """
    unannotated = sorted(set(tracks) - set(annotations))
    if unannotated:
        raise InputError(f"{len(unannotated)} frame(s) have tracks but no annotations, "
                         f"e.g. {unannotated[0]}")
    accumulator = motmetrics.MOTAccumulator(auto_id=True)
    for name in sorted(annotations, key=_frame_order):
        objects = annotations[name]
        gt_boxes, difficult = ground_truth_arrays(objects)
        boxes, ids, scores = tracks.get(name, (np.zeros((0, 4)), np.zeros(0, int), np.zeros(0)))
        boxes = as_box_array(boxes, "boxes")
        ids = np.asarray(ids).reshape(-1)
        scores = np.asarray(scores, dtype=np.float64).reshape(-1)
        if not len(ids) == len(scores) == len(boxes):
            raise InputError(f"{name}: {len(boxes)} boxes, {len(ids)} track ids, "
                             f"{len(scores)} scores")
        match = match_image(boxes, scores, gt_boxes, difficult, iou_threshold, difficult_cover)
        kept = match.labels != IGNORED
        vehicles = [obj for obj, hard in zip(objects, difficult) if not hard]
        if any(obj["id"] is None for obj in vehicles):
            raise InputError(f"{name}: a vehicle without an \"id\"; tracking metrics need "
                             f"identities")
        iou = iou_matrix(gt_boxes[~difficult], boxes[kept])
        distance = np.where(iou >= iou_threshold, 1.0 - iou, np.nan)
        accumulator.update([obj["id"] for obj in vehicles], ids[kept].tolist(), distance)
    summary = motmetrics.metrics.create().compute(accumulator, metrics=list(METRICS),
                                                  name="video").loc["video"]
    matched = int(summary["num_objects"] - summary["num_misses"])
    return TrackingReport(
        mota=float(summary["mota"]),
        motp=1.0 - float(summary["motp"]) if matched else math.nan,
        idf1=float(summary["idf1"]),
        id_switches=int(summary["num_switches"]),
        fragmentations=int(summary["num_fragmentations"]),
        false_positives=int(summary["num_false_positives"]),
        misses=int(summary["num_misses"]),
        objects=int(summary["num_objects"]),
        vehicles=int(summary["num_unique_objects"]),
        mostly_tracked=int(summary["mostly_tracked"]),
        mostly_lost=int(summary["mostly_lost"]),
        frames=len(annotations),
    )


def _frame_order(name):
    number = frame_number(name)
    return (0, number, name) if number is not None else (1, 0, name)
