"""Tests for ``fastdet.evaluation.metrics`` on hand-computed cases and a brute-force AP."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fastdet.detector.detections import Detections
from fastdet.detector.geometry import cover_matrix, iou_matrix
from fastdet.errors import InputError
from fastdet.evaluation.annotations import load_annotations, load_splits, select_split
from fastdet.evaluation.matching import (
    DIFFICULT_COVER,
    FALSE_POSITIVE,
    IGNORED,
    TRUE_POSITIVE,
    match_image,
)
from fastdet.evaluation.metrics import average_precision, evaluate

TP, FP, IGN = TRUE_POSITIVE, FALSE_POSITIVE, IGNORED


def car(box, difficult=False):
    return {"box": [float(v) for v in box], "label": "car", "difficult": difficult}


# -- iou_matrix -----------------------------------------------------------

def test_iou_uses_exclusive_corners():
    # 10x10 box and its left half: intersection 50, union 100.
    iou = iou_matrix([[0, 0, 10, 10]], [[0, 0, 5, 10], [10, 0, 20, 10], [0, 0, 10, 10]])
    np.testing.assert_array_equal(iou, [[0.5, 0.0, 1.0]])
    assert iou.dtype == np.float64


def test_iou_partial_overlap_and_shape():
    # Overlap 5x5 = 25; union 100 + 100 - 25 = 175.
    iou = iou_matrix([[0, 0, 10, 10], [100, 100, 110, 110]], [[5, 5, 15, 15]])
    assert iou.shape == (2, 1)
    assert iou[0, 0] == pytest.approx(25 / 175)
    assert iou[1, 0] == 0.0


def test_iou_empty_and_degenerate():
    assert iou_matrix(np.zeros((0, 4)), [[0, 0, 1, 1]]).shape == (0, 1)
    assert iou_matrix([[0, 0, 1, 1]], []).shape == (1, 0)
    # Zero-area boxes: empty union gives 0, not NaN.
    assert iou_matrix([[3, 3, 3, 3]], [[3, 3, 3, 3]])[0, 0] == 0.0


def test_iou_rejects_bad_shape():
    with pytest.raises(InputError, match="shape"):
        iou_matrix([[0, 0, 1]], [[0, 0, 1, 1]])


# -- match_image ----------------------------------------------------------

def test_perfect_match():
    gt = [[0, 0, 10, 10], [20, 20, 40, 40]]
    match = match_image(gt, [0.9, 0.8], gt, [False, False])
    np.testing.assert_array_equal(match.labels, [TP, TP])
    np.testing.assert_array_equal(match.ious, [1.0, 1.0])
    np.testing.assert_array_equal(match.matched_gt, [0, 1])
    assert (match.tp, match.fp, match.fn, match.n_positives) == (2, 0, 0, 2)


def test_a_missed_box_is_a_false_negative():
    match = match_image([[0, 0, 10, 10]], [1.0], [[0, 0, 10, 10], [50, 50, 60, 60]])
    assert (match.tp, match.fp, match.fn) == (1, 0, 1)
    np.testing.assert_array_equal(match.gt_found, [True, False])


def test_a_false_positive_reports_its_best_overlap():
    # The second prediction overlaps the box by 25/175 only.
    match = match_image([[0, 0, 10, 10], [5, 5, 15, 15], [90, 90, 99, 99]], [0.9, 0.8, 0.7],
                        [[0, 0, 10, 10]])
    np.testing.assert_array_equal(match.labels, [TP, FP, FP])
    np.testing.assert_allclose(match.ious, [1.0, 25 / 175, 0.0])
    np.testing.assert_array_equal(match.matched_gt, [0, -1, -1])


def test_a_match_on_a_difficult_box_is_ignored():
    match = match_image([[0, 0, 10, 10], [1, 0, 11, 10]], [0.9, 0.5], [[0, 0, 10, 10]], [True])
    # Both are ignored: a difficult box absorbs any number of detections.
    np.testing.assert_array_equal(match.labels, [IGN, IGN])
    assert (match.tp, match.fp, match.fn, match.ignored, match.n_positives) == (0, 0, 0, 2, 0)
    np.testing.assert_array_equal(match.gt_found, [False])


def test_a_missed_difficult_box_is_not_a_false_negative():
    match = match_image(np.zeros((0, 4)), [], [[0, 0, 10, 10], [20, 0, 30, 10]], [True, False])
    assert (match.fn, match.n_positives) == (1, 1)


def test_best_overlap_decides_between_difficult_and_normal_boxes():
    # The prediction overlaps the difficult box more (IoU 1.0 vs 0.6): ignored,
    # and the normal box stays available for the next prediction.
    gt = [[0, 0, 10, 10], [4, 0, 14, 10]]
    match = match_image([[0, 0, 10, 10], [4, 0, 14, 10]], [0.9, 0.1], gt, [True, False])
    np.testing.assert_array_equal(match.labels, [IGN, TP])
    np.testing.assert_array_equal(match.matched_gt, [0, 1])


def test_a_box_mostly_inside_a_difficult_box_is_ignored():
    # IoU 40 / 100 = 0.4 < 0.5, but the whole 4x10 detection lies inside the difficult box.
    match = match_image([[0, 0, 4, 10]], [0.9], [[0, 0, 10, 10]], [True])
    assert match.labels.tolist() == [IGN]
    assert match.matched_gt.tolist() == [0]
    assert match.ious[0] == pytest.approx(0.4)
    assert (match.tp, match.fp, match.ignored) == (0, 0, 1)


def test_coverage_rule_threshold_is_inclusive_and_needs_one_box():
    gt, difficult = [[0, 0, 10, 10], [10, 0, 20, 10]], [True, True]
    # Exactly half of a 20x10 box inside the first difficult box: ignored.
    assert match_image([[0, 0, 20, 10]], [1.0], [[0, 0, 10, 10]], [True]).labels.tolist() \
        == [IGN]
    # 40 % inside each of two difficult boxes: no single box holds half of it.
    match = match_image([[2, 0, 27, 10]], [1.0], gt + [[50, 50, 60, 60]], difficult + [False])
    assert match.labels.tolist() == [FP]


def test_a_box_mostly_on_background_stays_a_false_positive():
    # A 20x20 detection with a quarter of its area on a difficult 10x10 car.
    match = match_image([[0, 0, 20, 20]], [1.0], [[0, 0, 10, 10]], [True])
    assert match.labels.tolist() == [FP]
    assert match.fp == 1


def test_coverage_rule_never_applies_to_normal_boxes():
    # Wholly inside a non-difficult box, IoU 1/3: a false positive (poor localisation).
    match = match_image([[0, 0, 10, 10]], [1.0], [[0, 0, 30, 10]], [False])
    assert match.labels.tolist() == [FP]
    assert match.fn == 1


def test_a_true_positive_is_not_turned_into_an_ignored_one():
    # The detection matches the normal car (IoU 0.8) and also lies inside a big difficult box.
    gt = [[0, 0, 10, 10], [0, 0, 40, 40]]
    match = match_image([[0, 0, 10, 8]], [1.0], gt, [False, True])
    assert match.labels.tolist() == [TP]
    assert match.gt_found.tolist() == [True, False]


def test_plain_voc_rule_when_coverage_is_disabled():
    match = match_image([[0, 0, 4, 10]], [0.9], [[0, 0, 10, 10]], [True], difficult_cover=None)
    assert match.labels.tolist() == [FP]
    report = evaluate({"a.jpg": ([[0, 0, 4, 10]], [0.9])},
                      {"a.jpg": [car([0, 0, 10, 10], difficult=True)]}, difficult_cover=None)
    assert (report.fp, report.ignored, report.precision) == (1, 0, 0.0)
    assert report.to_dict()["difficult_cover"] is None


def test_evaluate_applies_the_coverage_rule_by_default():
    annotations = {"a.jpg": [car([0, 0, 10, 10], difficult=True), car([50, 0, 70, 20])]}
    results = {"a.jpg": ([[0, 0, 4, 10], [50, 0, 70, 20]], [0.9, 0.8])}
    report = evaluate(results, annotations)
    assert DIFFICULT_COVER == 0.5
    assert (report.tp, report.fp, report.ignored, report.precision) == (1, 0, 1, 1.0)
    assert report.to_dict()["difficult_cover"] == 0.5


def test_cover_matrix():
    cover = cover_matrix([[0, 0, 10, 10], [5, 5, 5, 9]], [[5, 0, 20, 10], [0, 0, 2, 2]])
    np.testing.assert_allclose(cover, [[0.5, 0.04], [0.0, 0.0]])


def test_duplicate_detection_is_a_false_positive():
    # The lower-scored duplicate is given first: order of visit is by score.
    match = match_image([[1, 0, 11, 10], [0, 0, 10, 10]], [0.3, 0.9], [[0, 0, 10, 10]])
    np.testing.assert_array_equal(match.labels, [FP, TP])
    # The duplicate's IoU (90/110) is still reported for diagnostics.
    assert match.ious[0] == pytest.approx(90 / 110)


def test_duplicate_takes_the_next_best_unmatched_box():
    # Two adjacent cars; the best prediction covers the left one, a second
    # prediction matching the left one best but the right one well enough
    # goes to the right one (best IoU among *unmatched* boxes).
    # IoU of the second prediction: 90/110 with the left box, 80/120 with the right.
    gt = [[0, 0, 10, 10], [3, 0, 13, 10]]
    match = match_image([[0, 0, 10, 10], [1, 0, 11, 10]], [0.9, 0.8], gt)
    np.testing.assert_array_equal(match.labels, [TP, TP])
    np.testing.assert_array_equal(match.matched_gt, [0, 1])


def test_iou_exactly_at_threshold_matches():
    # Left half of the box: IoU exactly 0.5, computed without rounding.
    match = match_image([[0, 0, 5, 10]], [1.0], [[0, 0, 10, 10]], iou_threshold=0.5)
    np.testing.assert_array_equal(match.labels, [TP])
    just_below = match_image([[0, 0, 5, 10]], [1.0], [[0, 0, 10, 10]],
                             iou_threshold=np.nextafter(0.5, 1.0))
    np.testing.assert_array_equal(just_below.labels, [FP])


def test_empty_predictions():
    match = match_image(np.zeros((0, 4)), np.zeros(0), [[0, 0, 10, 10]])
    assert match.labels.shape == (0,)
    assert (match.tp, match.fp, match.fn) == (0, 0, 1)


def test_empty_ground_truth():
    match = match_image([[0, 0, 10, 10]], [0.5], np.zeros((0, 4)), np.zeros(0, bool))
    np.testing.assert_array_equal(match.labels, [FP])
    np.testing.assert_array_equal(match.ious, [0.0])
    assert (match.tp, match.fp, match.fn, match.n_positives) == (0, 1, 0, 0)


def test_match_rejects_mismatched_lengths():
    with pytest.raises(InputError, match="scores"):
        match_image([[0, 0, 1, 1]], [0.1, 0.2], [[0, 0, 1, 1]])
    with pytest.raises(InputError, match="difficult"):
        match_image([[0, 0, 1, 1]], [0.1], [[0, 0, 1, 1]], [True, False])


# -- evaluate ---------------------------------------------------------------

def test_evaluate_pools_images_by_score():
    annotations = {
        "a.jpg": [car([0, 0, 10, 10]), car([20, 0, 30, 10]), car([50, 50, 60, 60], True)],
        "b.jpg": [car([0, 0, 10, 10])],
        "c.jpg": [],
    }
    results = {
        # TP (0.9), ignored on the difficult box (0.8), duplicate FP (0.4).
        "a.jpg": (np.array([[0, 0, 10, 10], [50, 50, 60, 60], [0, 0, 10, 10]]),
                  np.array([0.9, 0.8, 0.4])),
        # A FP on background (0.7) and a TP with IoU 0.8 (0.6), via Detections.
        "b.jpg": Detections([[100, 100, 110, 110], [0, 0, 8, 10]], [0.7, 0.6]),
        # c.jpg is absent: no predictions there.
    }
    report = evaluate(results, annotations)
    assert (report.tp, report.fp, report.fn, report.n_gt, report.ignored) == (2, 2, 1, 3, 1)
    assert report.precision == pytest.approx(2 / 4)
    assert report.recall == pytest.approx(2 / 3)
    assert report.mean_iou == pytest.approx((1.0 + 0.8) / 2)
    # numpy's linear interpolation between the two: 0.8 + 0.1 * (1.0 - 0.8).
    assert report.iou_p10 == pytest.approx(0.82)
    # Ranked (ignored dropped): 0.9 TP, 0.7 FP, 0.6 TP, 0.4 FP.
    # Precision envelope at the two recall steps: 1 and 2/3.
    assert report.ap == pytest.approx(1 / 3 * 1.0 + 1 / 3 * 2 / 3)
    assert set(report.per_image) == {"a.jpg", "b.jpg", "c.jpg"}
    images = report.to_dict()["images"]
    assert images["a.jpg"] == {
        "tp": 1, "fp": 1, "fn": 1, "ignored": 1,
        "false_positives": [{"box": [0, 0, 10, 10], "score": 0.4, "kind": "duplicate"}],
        "misses": [{"box": [20, 0, 30, 10], "near": False}]}
    # Detections keep float32 scores.
    assert images["b.jpg"]["false_positives"] == [
        {"box": [100, 100, 110, 110], "score": float(np.float32(0.7)), "kind": "background"}]
    assert images["c.jpg"]["false_positives"] == images["c.jpg"]["misses"] == []


def test_evaluate_perfect_detector():
    annotations = {"a.jpg": [car([0, 0, 10, 10])], "b.jpg": [car([5, 5, 25, 25])]}
    results = {"a.jpg": ([[0, 0, 10, 10]], [1.0]), "b.jpg": ([[5, 5, 25, 25]], [0.2])}
    report = evaluate(results, annotations)
    assert (report.precision, report.recall, report.ap, report.mean_iou) == (1.0, 1.0, 1.0, 1.0)


def test_evaluate_without_predictions():
    report = evaluate({}, {"a.jpg": [car([0, 0, 10, 10])]})
    assert (report.tp, report.fp, report.fn) == (0, 0, 1)
    assert report.precision == 1.0  # no predictions: no wrong claims
    assert report.recall == 0.0
    assert report.ap == 0.0
    assert report.mean_iou == report.iou_p10 == 0.0
    assert report.undefined() == {"precision", "mean_iou", "iou_p10"}
    summary = report.to_dict()
    assert summary["precision"] is summary["mean_iou"] is summary["iou_p10"] is None
    assert (summary["recall"], summary["ap"]) == (0.0, 0.0)   # defined: nothing found


def test_evaluate_without_ground_truth():
    report = evaluate({"a.jpg": ([[0, 0, 10, 10]], [0.5])},
                      {"a.jpg": [car([0, 0, 10, 10], difficult=True)], "b.jpg": []})
    assert (report.tp, report.fp, report.fn, report.n_gt, report.ignored) == (0, 0, 0, 0, 1)
    assert report.precision == 1.0
    assert report.recall == 1.0  # nothing to find
    assert report.ap == 0.0      # undefined, 0 for a search to rank
    assert report.undefined() == {"precision", "recall", "ap", "mean_iou", "iou_p10"}
    assert json.loads(json.dumps(report.to_dict()))["recall"] is None


def test_only_figures_without_a_denominator_are_undefined():
    annotations = {"a.jpg": [car([0, 0, 10, 10])], "b.jpg": []}
    found = evaluate({"a.jpg": ([[0, 0, 10, 10]], [0.5])}, annotations)
    assert found.undefined() == set()
    assert None not in found.to_dict(per_image=False).values()
    # A false box alone: precision 0 and AP 0 are figures, the IoU of no match is not.
    false = evaluate({"b.jpg": ([[0, 0, 10, 10]], [0.5])}, annotations)
    assert false.undefined() == {"mean_iou", "iou_p10"}
    assert (false.precision, false.recall, false.ap) == (0.0, 0.0, 0.0)


def test_evaluate_rejects_unannotated_images():
    with pytest.raises(InputError, match="no annotations: x.jpg"):
        evaluate({"x.jpg": ([[0, 0, 1, 1]], [1.0])}, {"a.jpg": []})


# -- average precision against a brute-force definition ---------------------

def brute_force_ap(labels, scores, n_positives):
    """Sum over true positives, in rank order, of the best precision at that
    rank or below, divided by the number of positives."""
    keep = [i for i in range(len(labels)) if labels[i] != IGNORED]
    ranked = sorted(keep, key=lambda i: -scores[i])
    total = 0.0
    for rank, i in enumerate(ranked):
        if labels[i] != TRUE_POSITIVE:
            continue
        best = 0.0
        for cut in range(rank, len(ranked)):
            hits = sum(labels[j] == TRUE_POSITIVE for j in ranked[:cut + 1])
            best = max(best, hits / (cut + 1))
        total += best
    return total / n_positives


@pytest.mark.parametrize("seed", range(20))
def test_average_precision_matches_brute_force(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 40))
    labels = rng.choice([TP, FP, IGN], size=n, p=[0.4, 0.5, 0.1])
    scores = rng.permutation(n) + rng.uniform(0, 0.5, n)  # distinct scores
    n_positives = int(np.count_nonzero(labels == TP) + rng.integers(0, 5))
    if n_positives == 0:
        n_positives = 1
    assert average_precision(labels, scores, n_positives) == pytest.approx(
        brute_force_ap(labels.tolist(), scores.tolist(), n_positives), abs=1e-12)


@pytest.mark.parametrize("seed", range(5))
def test_evaluate_ap_matches_brute_force_on_random_scenes(seed):
    rng = np.random.default_rng(100 + seed)
    annotations, results = {}, {}
    for image in range(4):
        gt = rng.integers(0, 200, (int(rng.integers(0, 5)), 2))
        annotations[f"{image}.jpg"] = [car([x, y, x + 40, y + 30], bool(rng.random() < 0.2))
                                       for x, y in gt]
        # Jittered copies of the boxes plus random ones.
        jittered = [[x + d, y + e, x + 40 + d, y + 30 + e]
                    for x, y in gt for d, e in [rng.integers(-12, 13, 2)]]
        random = [[x, y, x + 40, y + 30] for x, y in rng.integers(0, 200, (3, 2))]
        boxes = np.array(jittered + random, dtype=float).reshape(-1, 4)
        results[f"{image}.jpg"] = (boxes, rng.uniform(0, 1, len(boxes)))
    report = evaluate(results, annotations)
    labels = np.concatenate([m.labels for m in report.per_image.values()])
    scores = np.concatenate([m.scores for m in report.per_image.values()])
    if report.n_gt:
        assert report.ap == pytest.approx(brute_force_ap(labels.tolist(), scores.tolist(),
                                                         report.n_gt), abs=1e-12)
    assert report.tp + report.fp + report.ignored == len(labels)


def test_average_precision_edge_cases():
    assert average_precision([], [], 0) == 0.0
    assert average_precision([], [], 3) == 0.0
    assert average_precision([TP, TP], [2.0, 1.0], 2) == 1.0
    # A FP ranked first halves the precision of the only TP.
    assert average_precision([FP, TP], [2.0, 1.0], 1) == 0.5


# -- load_annotations -------------------------------------------------------

def write(tmp_path, content):
    path = tmp_path / "annotations.json"
    path.write_text(content if isinstance(content, str) else json.dumps(content))
    return path


def test_load_annotations_normalises(tmp_path):
    path = write(tmp_path, {"format": "description", "images": {
        "a.jpg": [{"box": [1, 2, 3, 4], "label": "car", "difficult": True, "id": 7},
                  {"box": [0, 0, 5.5, 5]}],
        "b.jpg": []}})
    assert load_annotations(path) == {
        "a.jpg": [{"box": [1.0, 2.0, 3.0, 4.0], "label": "car", "difficult": True, "id": 7},
                  {"box": [0.0, 0.0, 5.5, 5.0], "label": "car", "difficult": False, "id": None}],
        "b.jpg": []}


def test_splits_select_their_images(tmp_path):
    path = write(tmp_path, {"images": {"frame1": [], "frame2": [], "frame3": []},
                            "frames": {"development": ["frame1"], "held_out": ["frame3"]}})
    annotations, splits = load_annotations(path), load_splits(path)
    assert splits == {"development": ["frame1"], "held_out": ["frame3"]}
    assert select_split(annotations, splits, "held_out") == {"frame3": []}
    assert select_split(annotations, splits, None) is annotations
    with pytest.raises(InputError, match="no split 'test'.*development, held_out"):
        select_split(annotations, splits, "test")
    assert load_splits(write(tmp_path, {"images": {}})) == {}


@pytest.mark.parametrize("frames, message", [
    ([], "must map split names"),
    ({"development": "frame1"}, "must be a list of image names"),
    ({"development": ["frame9"]}, "no annotations, e.g. 'frame9'"),
])
def test_split_errors(tmp_path, frames, message):
    path = write(tmp_path, {"images": {"frame1": []}, "frames": frames})
    with pytest.raises(InputError, match=message):
        load_splits(path)


def test_ids_may_repeat_across_frames_and_names_may_share_digits(tmp_path):
    content = {"images": {"frame1": [{"box": [0, 0, 1, 1], "id": 4}, {"box": [2, 2, 3, 3]},
                                     {"box": [4, 4, 5, 5]}],
                          "frame10": [{"box": [0, 0, 1, 1], "id": 4}],
                          "frame1.jpg": [], "a.jpg": []}}
    assert set(load_annotations(write(tmp_path, content))) == set(content["images"])


def test_load_annotations_missing_file(tmp_path):
    with pytest.raises(InputError, match="annotation file not found"):
        load_annotations(tmp_path / "nope.json")


def test_load_annotations_not_json(tmp_path):
    with pytest.raises(InputError, match="is not valid JSON"):
        load_annotations(write(tmp_path, "{images: "))


@pytest.mark.parametrize("content, message", [
    ([1, 2], '"images" object'),
    ({"imgs": {}}, '"images" object'),
    ({"images": {"a.jpg": {"box": [0, 0, 1, 1]}}}, "must be a list"),
    ({"images": {"a.jpg": ["box"]}}, "must be an object"),
    ({"images": {"a.jpg": [{"label": "car"}]}}, "box must be a list of 4"),
    ({"images": {"a.jpg": [{"box": [0, 0, 1]}]}}, "box must be a list of 4"),
    ({"images": {"a.jpg": [{"box": [0, 0, "1", 1]}]}}, "box must be a list of 4"),
    ({"images": {"a.jpg": [{"box": [0, 0, True, 1]}]}}, "box must be a list of 4"),
    ({"images": {"a.jpg": [{"box": [5, 0, 5, 1]}]}}, "x2 > x1"),
    # Finite, but areas and overlaps overflowed (NumPy's warnings on stderr):
    ({"images": {"a.jpg": [{"box": [0, 0, 1e308, 1e308]}]}}, "at most 1e\\+07 in size"),
    ({"images": {"a.jpg": [{"box": [-1e8, 0, 1, 1]}]}}, "at most 1e\\+07 in size"),
    ({"images": {"a.jpg": [{"box": [0, 0, 1, 1], "difficult": "yes"}]}}, "difficult must be"),
    ({"images": {"a.jpg": [{"box": [0, 0, 1, 1], "label": 3}]}}, "label must be"),
    ({"images": {"a.jpg": [{"box": [0, 0, 1, 1], "id": "seven"}]}}, "id must be an integer"),
    ({"images": {"a.jpg": [{"box": [0, 0, 1, 1], "id": True}]}}, "id must be an integer"),
    # IDF1 came out as 1.5 with one vehicle boxed twice in a frame.
    ({"images": {"frame3": [{"box": [0, 0, 1, 1], "id": 1}, {"box": [5, 5, 9, 9], "id": 1}]}},
     "images\\['frame3'\\] has 2 vehicles with id 1"),
    # One of them was scored against the frame's detections, the other against none.
    ({"images": {"frame1": [], "frame01": []}},
     "images 'frame1' and 'frame01' are the same video frame \\(1\\)"),
])
def test_load_annotations_structure_errors(tmp_path, content, message):
    with pytest.raises(InputError, match=message) as info:
        load_annotations(write(tmp_path, content))
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("iou", [0, -1, 1.5, float("nan")])
def test_evaluate_rejects_a_match_iou_outside_zero_one(iou):
    with pytest.raises(InputError, match="match IoU"):
        evaluate({}, {}, iou_threshold=iou)


@pytest.mark.parametrize("cover", [0, -0.5, 1.5])
def test_evaluate_rejects_a_cover_outside_zero_one(cover):
    with pytest.raises(InputError, match="difficult_cover"):
        evaluate({}, {"a.jpg": []}, difficult_cover=cover)


@pytest.mark.parametrize("text, key", [
    ('{"images": {"frame0": [{"box": [0, 0, 10, 10]}], "frame0": []}}', "frame0"),
    ('{"images": {"a.jpg": [{"box": [0, 0, 10, 10], "box": [5, 5, 20, 20]}]}}', "box"),
    ('{"images": {"a.jpg": []}, "images": {}}', "images"),
])
def test_a_key_given_twice_is_an_error(tmp_path, text, key):
    """JSON kept the last of them silently: a frame's boxes, or a first box, were lost."""
    path = tmp_path / "a.json"
    path.write_text(text)
    with pytest.raises(InputError, match=f"a.json: '{key}' is given twice in one JSON object"):
        load_annotations(path)


@pytest.mark.parametrize("name", ["frame\u00b2", "frame\u0663"])
def test_a_frame_number_is_ascii_digits(tmp_path, name):
    """``"frame²"`` passed ``str.isdigit`` and crashed ``int`` (an internal error, exit
    70); ``"frame٣"`` was read as frame 3.  Neither is a video frame's name."""
    from fastdet.evaluation.annotations import frame_number
    from fastdet.video.evaluate import frame_index

    path = write(tmp_path, {"images": {name: [{"box": [0, 0, 10, 10]}]}})
    assert list(load_annotations(path)) == [name]
    assert frame_number(name) is None
    with pytest.raises(InputError, match="video annotations name frames frame<N>"):
        frame_index(name)
