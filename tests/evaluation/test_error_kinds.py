"""Tests for the error kinds of ``fastdet.evaluation.error_kinds`` and the AP gains of
``fastdet.evaluation.metrics.error_summary``."""

from __future__ import annotations

import numpy as np
import pytest

from fastdet.detector.geometry import iou_matrix
from fastdet.evaluation.error_kinds import (
    BACKGROUND,
    DIFFICULT,
    DUPLICATE,
    FALSE_BOX_KINDS,
    LOCALISATION,
    NEAR_IOU,
    NOT_AN_ERROR,
)
from fastdet.evaluation.matching import FALSE_POSITIVE, IGNORED, TRUE_POSITIVE, match_image
from fastdet.evaluation.metrics import evaluate

from .test_evaluate import brute_force_ap, car

A, B, C = [0, 0, 100, 100], [300, 0, 400, 100], [600, 0, 700, 100]
HARD = [0, 300, 100, 400]


def kinds_of(pred, scores, gt, difficult=None):
    return match_image(pred, scores, gt, difficult).error_kinds.tolist()


def test_each_kind_of_false_box():
    pred = [A,                   # finds A
            [5, 5, 105, 105],    # A again: a duplicate
            [300, 0, 340, 100],  # 40 % of B's width: IoU 0.4, a localisation error
            [0, 300, 100, 600],  # a difficult car's box three times its height: IoU 1/3
            [900, 900, 950, 950]]  # nothing
    match = match_image(pred, [0.9, 0.8, 0.7, 0.6, 0.5], [A, B, HARD],
                        [False, False, True], difficult_cover=0.5)
    assert match.labels.tolist() == [TRUE_POSITIVE] + [FALSE_POSITIVE] * 4
    assert match.error_kinds.tolist() == [NOT_AN_ERROR, DUPLICATE, LOCALISATION, DIFFICULT,
                                          BACKGROUND]
    assert match.error_vehicles.tolist() == [-1, 0, 1, -1, -1]
    # B is missed with a false box near it.
    assert match.near_misses.tolist() == [False, True, False]


def test_verdicts_name_each_prediction():
    pred = [A, [5, 5, 105, 105], [0, 300, 100, 400], [900, 900, 950, 950]]
    match = match_image(pred, [0.9, 0.8, 0.7, 0.6], [A, HARD], [False, True])
    assert match.verdicts() == ["match", "duplicate", "ignored", "background"]


def test_ignored_boxes_are_not_errors():
    # Half inside the difficult car: the coverage rule ignores it, so it is no error.
    match = match_image([[0, 300, 100, 500]], [1.0], [HARD], [True])
    assert match.labels.tolist() == [IGNORED]
    assert match.error_kinds.tolist() == [NOT_AN_ERROR]


def test_the_near_threshold_is_inclusive():
    # A box [0, 0, 10, 100] inside A has IoU exactly 0.1 with it.
    assert iou_matrix([[0, 0, 10, 100]], [A])[0, 0] == pytest.approx(NEAR_IOU)
    assert kinds_of([[0, 0, 10, 100]], [1.0], [A]) == [LOCALISATION]
    assert kinds_of([[0, 0, 9, 100]], [1.0], [A]) == [BACKGROUND]


def test_a_duplicate_outranks_a_localisation_error_and_a_difficult_car():
    # The second box overlaps found A at 0.9, a difficult car at 0.27 and C a little.
    gt = [A, [50, 0, 150, 100], [-90, 0, 10, 100]]
    pred = [A, [0, 0, 90, 100]]
    match = match_image(pred, [1.0, 0.5], gt, [False, True, False])
    assert match.error_kinds.tolist() == [NOT_AN_ERROR, DUPLICATE]


def test_a_miss_without_any_box_near_is_not_a_near_miss():
    match = match_image([A], [1.0], [A, B])
    assert match.near_misses.tolist() == [False, False]
    assert match.fn == 1


def test_summary_counts_and_gains_by_hand():
    # Ranked: background (0.9), TP on A (0.8), localisation on B (0.7); C missed with nothing near.
    annotations = {"a.jpg": [car(A), car(B), car(C)]}
    results = {"a.jpg": (np.array([[900, 900, 950, 950], A, [300, 0, 340, 100]], float),
                         np.array([0.9, 0.8, 0.7]))}
    report = evaluate(results, annotations)
    errors = report.errors
    assert errors["false_positives"] == {"duplicate": 0, "localisation": 1, "difficult": 0,
                                         "background": 1}
    assert errors["misses"] == {"near": 1, "missed": 1}
    # As it is: recall 1/3 at precision 1/2 -> AP 1/6.
    assert report.ap == pytest.approx(1 / 6)
    gains = errors["ap_gain"]
    # Background dropped: TP first -> recall 1/3 at precision 1 -> AP 1/3.
    assert gains["background"] == pytest.approx(1 / 3 - 1 / 6)
    # The localisation error finds B: FP, TP, TP -> precision 2/3 up to recall 2/3.
    assert gains["localisation"] == pytest.approx(2 / 3 * 2 / 3 - 1 / 6)
    # C not required: recall 1/2 at precision 1/2 -> AP 1/4.
    assert gains["missed"] == pytest.approx(1 / 4 - 1 / 6)
    assert gains["duplicate"] == gains["difficult"] == 0.0


def test_a_localisation_fix_finds_each_vehicle_once():
    # Two loose boxes on missed B: the higher-scoring one is fixed, the other dropped.
    annotations = {"a.jpg": [car(B)]}
    results = {"a.jpg": (np.array([[300, 0, 340, 100], [360, 0, 400, 100]], float),
                         np.array([0.5, 0.9]))}
    report = evaluate(results, annotations)
    assert report.errors["false_positives"]["localisation"] == 2
    assert report.errors["ap_gain"]["localisation"] == pytest.approx(1.0)


def _kind_by_brute_force(p, labels, iou, found, difficult, threshold):
    """One false box's kind, decided over the ground truth one box at a time."""
    if labels[p] != FALSE_POSITIVE:
        return NOT_AN_ERROR
    on_found = on_normal = on_difficult = False
    for g in range(iou.shape[1]):
        if not difficult[g] and found[g] and iou[p, g] >= threshold:
            on_found = True
        if not difficult[g] and iou[p, g] >= NEAR_IOU:
            on_normal = True
        if difficult[g] and iou[p, g] >= NEAR_IOU:
            on_difficult = True
    return (DUPLICATE if on_found else LOCALISATION if on_normal
            else DIFFICULT if on_difficult else BACKGROUND)


@pytest.mark.parametrize("seed", range(8))
def test_kinds_and_gains_match_brute_force_on_random_scenes(seed):
    rng = np.random.default_rng(200 + seed)
    annotations, results = {}, {}
    for image in range(3):
        corners = rng.integers(0, 200, (int(rng.integers(0, 5)), 2))
        annotations[f"{image}.jpg"] = [car([x, y, x + 40, y + 30], bool(rng.random() < 0.3))
                                       for x, y in corners]
        jittered = [[x + d, y + e, x + 40 + d, y + 30 + e]
                    for x, y in corners for _ in range(int(rng.integers(0, 3)))
                    for d, e in [rng.integers(-25, 26, 2)]]
        random = [[x, y, x + 40, y + 30] for x, y in rng.integers(0, 200, (3, 2))]
        results[f"{image}.jpg"] = (np.array(jittered + random, float).reshape(-1, 4),
                                   rng.permutation(len(jittered) + 3) + rng.uniform(0, 0.5))
    report = evaluate(results, annotations)
    all_labels, all_scores, all_kinds = [], [], []
    counts = dict.fromkeys(FALSE_BOX_KINDS, 0)
    for name, match in report.per_image.items():
        gt = np.array([o["box"] for o in annotations[name]], float).reshape(-1, 4)
        difficult = [o["difficult"] for o in annotations[name]]
        iou = iou_matrix(results[name][0], gt)
        for p in range(len(match.labels)):
            kind = _kind_by_brute_force(p, match.labels, iou, match.gt_found, difficult, 0.5)
            assert match.error_kinds[p] == kind
            if kind != NOT_AN_ERROR:
                counts[FALSE_BOX_KINDS[kind]] += 1
        all_labels += match.labels.tolist()
        all_scores += match.scores.tolist()
        all_kinds += match.error_kinds.tolist()
    assert report.errors["false_positives"] == counts
    if report.n_gt:
        for code in (DUPLICATE, DIFFICULT, BACKGROUND):
            kept = [k != code for k in all_kinds]
            fixed = brute_force_ap([lab for lab, keep in zip(all_labels, kept) if keep],
                                   [s for s, keep in zip(all_scores, kept) if keep], report.n_gt)
            assert report.errors["ap_gain"][FALSE_BOX_KINDS[code]] == pytest.approx(
                fixed - report.ap, abs=1e-12)
