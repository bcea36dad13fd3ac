"""Detections refuses what it would otherwise change on the way in."""

import json

import numpy as np
import pytest

from fastdet.detector.detections import Detections


def test_whole_numbers_of_any_type_are_kept():
    detections = Detections(np.array([[10.0, 20.0, 30.0, 40.0]]), [np.float16(0.5)], [7.0])
    assert detections.xyxy.dtype == np.int32 and detections.xyxy.tolist() == [[10, 20, 30, 40]]
    assert detections.score.dtype == np.float32 and detections.score.tolist() == [0.5]
    assert detections.track_id.dtype == np.int64 and detections.track_id.tolist() == [7]
    assert json.loads(json.dumps(detections.to_list())) == [
        {"box": [10, 20, 30, 40], "score": 0.5, "track": 7}]


def test_no_boxes_of_any_dtype():
    assert len(Detections(np.zeros((0, 4)), [], np.zeros(0))) == 0


@pytest.mark.parametrize("xyxy, message", [
    ([[10.5, 20, 30, 40]], "whole numbers"),          # would have become 10
    ([[np.nan, 20, 30, 40]], "whole numbers"),
    ([[10, 20, 30, 2 ** 31]], "between"),              # would have wrapped to -2**31
    ([[10, 20, 30, -2 ** 31 - 1]], "between"),
    ([["10", 20, 30, 40]], "integers"),
])
def test_box_coordinates_that_a_cast_would_change_are_refused(xyxy, message):
    with pytest.raises(ValueError, match=message):
        Detections(xyxy, [1.0])


@pytest.mark.parametrize("score", [np.nan, np.inf, -np.inf, 1e39])
def test_scores_json_cannot_carry_are_refused(score):
    # 1e39 is finite in float64 but infinite in the float32 the scores are kept in.
    with pytest.raises(ValueError, match="finite"):
        Detections([[10, 20, 30, 40]], [score])


def test_fractional_track_ids_are_refused():
    with pytest.raises(ValueError, match="track ids must be whole"):
        Detections([[10, 20, 30, 40]], [1.0], [1.5])


def test_the_largest_scores_and_coordinates_that_fit_are_kept():
    big = np.finfo(np.float32).max
    detections = Detections([[-2 ** 31, 0, 2 ** 31 - 1, 1]], [big])
    assert detections.xyxy.tolist() == [[-2 ** 31, 0, 2 ** 31 - 1, 1]]
    assert detections.score[0] == big
