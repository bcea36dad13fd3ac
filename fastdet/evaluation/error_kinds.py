"""What kind of error each false box and each miss is, and what fixing each kind is worth.

Precision and recall say how many boxes are wrong; a user tuning fastdet for
a camera of their own also needs to know *how* they are wrong: a box on
nothing calls for other negatives or a higher threshold, a box on a car that
misses it by a few pixels for the box refinement, a second box on one car
for the heat merge.  The kinds are those of TIDE (Bolya et al., "TIDE: A
General Toolbox for Identifying Object Detection Errors", ECCV 2020), for one
class and with difficult vehicles.  Its own package (``tidecv``) is not used:
it reads COCO files, knows crowd regions but not the difficult-vehicle rules
of :mod:`.matching`, and has had no release since 2020.

A false box (a prediction :func:`~.matching.match_image` labels
``FALSE_POSITIVE``) is, in this order of precedence:

``duplicate``
    IoU at or above the match threshold with a non-difficult vehicle that a
    higher-scoring box already found;
``localisation``
    IoU in ``[NEAR_IOU, threshold)`` with a non-difficult vehicle: a box on a
    vehicle, but offset, too loose or too tight, or one box over two cars;
``difficult``
    IoU at least ``NEAR_IOU`` with a difficult vehicle, without matching it
    or lying half inside it (the rules that ignore a box on one), typically a
    whole-car box on a car the annotation boxes only where it is visible;
``background``
    IoU below ``NEAR_IOU`` with every vehicle.

A missed non-difficult vehicle is ``near`` when a false box overlaps it at
IoU ``NEAR_IOU`` or more (the same error seen from the vehicle's side) and
``missed`` otherwise.  TIDE's background threshold is 0.1; so is ours.
"""

from __future__ import annotations

import numpy as np

#: Least IoU with a vehicle for a false box to count as placed on it (TIDE's t_b).
NEAR_IOU = 0.1

#: The kinds of false box, by their code in :attr:`~.matching.ImageMatch.error_kinds`.
FALSE_BOX_KINDS = ("duplicate", "localisation", "difficult", "background")
DUPLICATE, LOCALISATION, DIFFICULT, BACKGROUND = range(len(FALSE_BOX_KINDS))
#: Code of a prediction that is not a false box.
NOT_AN_ERROR = -1


def classify_errors(iou, false_box, gt_found, gt_difficult, iou_threshold, near=NEAR_IOU):
    """The kind of each false box and which misses have a false box near them.

    Parameters
    ----------
    iou : ndarray of float64, shape (N, M)
        IoU of every prediction with every ground-truth box.
    false_box : ndarray of bool, shape (N,)
        Which predictions the matching left false positives.
    gt_found : ndarray of bool, shape (M,)
        Which ground-truth boxes a true positive matched.
    gt_difficult : ndarray of bool, shape (M,)
    iou_threshold : float
        The match threshold.
    near : float
        Least IoU for a false box to be on a vehicle.

    Returns
    -------
    kinds : ndarray of int8, shape (N,)
        An index into :data:`FALSE_BOX_KINDS` per false box,
        :data:`NOT_AN_ERROR` for the other predictions.
    vehicle : ndarray of int64, shape (N,)
        For duplicates and localisation errors the vehicle concerned (the
        found one at the highest IoU, or the non-difficult one at the highest
        IoU); -1 otherwise.
    near_miss : ndarray of bool, shape (M,)
        Missed non-difficult vehicles that some false box overlaps at ``near``
        or more.
    """
    n_pred, n_gt = iou.shape
    normal = ~gt_difficult
    # Each prediction's best IoU with found, normal and difficult vehicles (-1: none).
    found_iou = np.where(normal & gt_found, iou, -1.0)
    normal_iou = np.where(normal, iou, -1.0)
    difficult_iou = np.where(gt_difficult, iou, -1.0)
    if n_gt:
        best_found, best_normal = found_iou.max(axis=1), normal_iou.max(axis=1)
        best_difficult = difficult_iou.max(axis=1)
    else:
        best_found = best_normal = best_difficult = np.full(n_pred, -1.0)
    kinds = np.select(
        [~false_box, best_found >= iou_threshold, best_normal >= near, best_difficult >= near],
        [NOT_AN_ERROR, DUPLICATE, LOCALISATION, DIFFICULT], BACKGROUND).astype(np.int8)
    vehicle = np.full(n_pred, -1, dtype=np.int64)
    if n_gt:
        vehicle[kinds == DUPLICATE] = found_iou.argmax(axis=1)[kinds == DUPLICATE]
        vehicle[kinds == LOCALISATION] = normal_iou.argmax(axis=1)[kinds == LOCALISATION]
    missed = normal & ~gt_found
    near_miss = missed & (iou[false_box] >= near).any(axis=0)
    return kinds, vehicle, near_miss
