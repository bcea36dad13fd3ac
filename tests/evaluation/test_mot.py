"""Tracking metrics through py-motmetrics, checked against figures worked out by hand."""

import numpy as np
import pytest

from fastdet.errors import InputError
from fastdet.evaluation.mot import tracking_metrics


def car(box, identity, difficult=False):
    return {"box": list(map(float, box)), "label": "car", "difficult": difficult, "id": identity}


A = [0, 0, 10, 10]
B = [50, 0, 60, 10]


def tracks_of(*frames):
    """``{frame<i>: (boxes, ids, scores)}`` from lists of ``(box, id)``."""
    out = {}
    for index, boxes in enumerate(frames):
        out[f"frame{index}"] = (np.array([b for b, _ in boxes], float).reshape(-1, 4),
                                np.array([i for _, i in boxes], int),
                                np.ones(len(boxes)))
    return out


def two_cars(frames):
    return {f"frame{i}": [car(A, 1), car(B, 2)] for i in range(frames)}


def test_a_perfect_tracker():
    report = tracking_metrics(tracks_of(*[[(A, 7), (B, 8)]] * 4), two_cars(4))
    assert (report.mota, report.idf1, report.motp) == (1.0, 1.0, 1.0)
    assert (report.id_switches, report.fragmentations, report.misses,
            report.false_positives) == (0, 0, 0, 0)
    assert (report.objects, report.vehicles, report.frames, report.mostly_tracked) == (8, 2, 4, 2)


def test_an_id_switch_and_a_gap():
    # Car 1 changes track id from 7 to 9 at frame 2 (one switch); car 2 is
    # missed at frame 1 and found again (one fragmentation, one miss); one
    # false positive far from both in frame 3.
    tracks = tracks_of([(A, 7), (B, 8)], [(A, 7)], [(A, 9), (B, 8)],
                       [(A, 9), (B, 8), ([200, 200, 210, 210], 5)])
    report = tracking_metrics(tracks, two_cars(4))
    assert (report.id_switches, report.fragmentations, report.misses,
            report.false_positives) == (1, 1, 1, 1)
    # MOTA = 1 - (misses + false positives + switches) / objects.
    assert report.mota == pytest.approx(1 - 3 / 8)
    # IDF1: the best one-to-one id matching is 1<->9 or 1<->7 (2 frames) and
    # 2<->8 (3 frames): IDTP 5 of 8 truths and 8 predictions.
    assert report.idf1 == pytest.approx(2 * 5 / (8 + 8))


def test_matching_needs_half_overlap():
    shifted = [6, 0, 16, 10]            # IoU 4/16 with A: no match
    report = tracking_metrics(tracks_of([(shifted, 1)]), {"frame0": [car(A, 1)]})
    assert (report.misses, report.false_positives, report.mota) == (1, 1, -1.0)
    close = [1, 0, 11, 10]              # IoU 9/11
    report = tracking_metrics(tracks_of([(close, 1)]), {"frame0": [car(A, 1)]})
    assert report.motp == pytest.approx(9 / 11)


def test_difficult_vehicles_are_neither_required_nor_penalised():
    truth = {"frame0": [car(A, 1), car(B, 2, difficult=True)]}
    report = tracking_metrics(tracks_of([(A, 1), (B, 3)]), truth)
    assert (report.objects, report.false_positives, report.misses, report.mota) == (1, 0, 0, 1.0)
    # Nor is a box mostly inside a difficult vehicle (the coverage rule)...
    inside = [50, 0, 54, 10]          # IoU 0.4, all of it inside
    assert tracking_metrics(tracks_of([(A, 1), (inside, 3)]), truth).false_positives == 0
    # ...unless the plain VOC rule is asked for.
    assert tracking_metrics(tracks_of([(A, 1), (inside, 3)]), truth,
                            difficult_cover=None).false_positives == 1


def test_frames_are_taken_in_index_order():
    # frame10 after frame9: compared as names, "frame10" < "frame9" and the
    # switch back to id 7 would be counted at the other end.
    truth = {f"frame{i}": [car(A, 1)] for i in (8, 9, 10)}
    tracks = {"frame8": ([A], [7], [1.0]), "frame9": ([A], [7], [1.0]),
              "frame10": ([A], [5], [1.0])}
    assert tracking_metrics(tracks, truth).id_switches == 1


def test_frames_without_vehicles():
    report = tracking_metrics(tracks_of([(A, 1)]), {"frame0": []})
    assert report.false_positives == 1 and report.objects == 0
    assert report.to_dict()["mota"] is None  # undefined, and JSON has no NaN
    assert report.to_dict()["motp"] is None  # no matched pair to average


def test_missing_frames_count_as_empty_and_unknown_frames_are_refused():
    report = tracking_metrics({}, two_cars(2))
    assert (report.misses, report.mota) == (4, 0.0)
    with pytest.raises(InputError, match="no annotations"):
        tracking_metrics(tracks_of([(A, 1)]), {})


def test_vehicles_need_identities():
    with pytest.raises(InputError, match="without an \"id\""):
        tracking_metrics({}, {"frame0": [car(A, None)]})
    # A difficult vehicle may go without one.
    tracking_metrics({}, {"frame0": [car(A, 1), car(B, None, difficult=True)]})
