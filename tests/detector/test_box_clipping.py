"""Rounding and clipping of refined boxes, the box filter and the heat weights, on the few
boxes of a frame.

Clipping and filtering run in plain Python per box (cheaper than NumPy on a
handful of rows), the weights in as few NumPy calls as each rule needs; all
must give what the plain NumPy rules give (halves rounded to even, weights bit
for bit).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from fastdet.detector.boxes import BoxFinder, _clipped
from fastdet.detector.config import BoxConfig, DetectorConfig, HeatConfig, SearchConfig
from fastdet.detector.scoring import Hits


def numpy_clipped(boxes, frame_size):
    out = np.round(boxes)
    width, height = frame_size
    out[:, 0] = np.clip(out[:, 0], 0, width - 1)
    out[:, 1] = np.clip(out[:, 1], 0, height - 1)
    out[:, 2] = np.minimum(np.maximum(out[:, 2], out[:, 0] + 1), width)
    out[:, 3] = np.minimum(np.maximum(out[:, 3], out[:, 1] + 1), height)
    return out.astype(np.int32)


@pytest.mark.parametrize("count", [0, 1, 7, 200])
def test_clipped_matches_numpy_rounding_and_clipping(count):
    rng = np.random.default_rng(count)
    boxes = rng.uniform(-50, 1400, (count, 4))
    # Halves (rounded to even), inverted and degenerate boxes, boxes outside.
    boxes[: count // 2] = np.round(boxes[: count // 2]) + 0.5
    if count >= 7:
        boxes[2] = [10.0, 20.0, 10.2, 19.7]
        boxes[3] = [1500.0, 800.0, 1600.0, 900.0]
        boxes[4] = [-30.0, -40.0, -10.0, -20.0]
    clipped = _clipped(boxes, (1280, 720))
    assert clipped.dtype == np.int32 and clipped.shape == (count, 4)
    np.testing.assert_array_equal(clipped, numpy_clipped(boxes, (1280, 720)))
    assert np.all(clipped[:, 2] > clipped[:, 0]) and np.all(clipped[:, 3] > clipped[:, 1])


@pytest.mark.parametrize("frame_size", [(1280, 720), (960, 540), (1917, 1079)])
def test_box_filter_matches_the_numpy_rule(frame_size):
    finder = BoxFinder(DetectorConfig(boxes=BoxConfig(min_size=24, min_aspect=0.5,
                                                      max_aspect=3.0, horizon_y=380)))
    rng = np.random.default_rng(frame_size[0])
    corners = rng.integers(0, 700, (300, 2))
    boxes = np.concatenate([corners, corners + rng.integers(1, 120, (300, 2))],
                           axis=1).astype(np.int32)
    k = np.sqrt(frame_size[0] / 1280 * frame_size[1] / 720)
    width, height = boxes[:, 2] - boxes[:, 0], boxes[:, 3] - boxes[:, 1]
    aspect = width / np.maximum(height, 1)
    expected = ((width >= 24 * k) & (height >= 24 * k) & (aspect >= 0.5) & (aspect <= 3.0)
                & (boxes[:, 3] > 380 * frame_size[1] / 720))
    kept = finder.box_filter(boxes, frame_size)
    assert kept.dtype == bool
    np.testing.assert_array_equal(kept, expected)
    assert 0 < kept.sum() < len(boxes)
    assert finder.box_filter(np.zeros((0, 4), np.int32), frame_size).shape == (0,)


def numpy_heat_weights(hits, plans, weighting, threshold):
    """The heat weights as the NumPy expressions of the heat's definition give them."""
    weights = np.ones(len(hits.scores), dtype=np.float32)
    if weighting in ("margin", "margin_area"):
        weights = (hits.scores - threshold).astype(np.float32)
    if weighting in ("area", "margin_area") and len(hits.scores):
        per_scale = np.array([plan.heat_weight for plan in plans], dtype=np.float32)
        weights = weights * per_scale[hits.scale_index]
    return weights


@pytest.mark.parametrize("weighting", ["count", "area", "margin", "margin_area"])
@pytest.mark.parametrize("threshold", [-0.5, 0.1, 0.3])
@pytest.mark.parametrize("score_dtype", [np.float32, np.float64])
def test_heat_weights_match_numpy(weighting, threshold, score_dtype):
    rng = np.random.default_rng(7)
    count = 40
    scores = rng.normal(0.5, 1.0, count).astype(score_dtype)
    hits = Hits(np.zeros((count, 4), np.int32), scores, rng.integers(0, 3, count), 800)
    plans = [SimpleNamespace(heat_weight=w) for w in (0.25, 1.0, 2.5)]
    config = DetectorConfig(search=SearchConfig(decision_threshold=threshold),
                            heat=HeatConfig(weighting=weighting))
    weights = BoxFinder(config).heat_weights(hits, plans)
    expected = numpy_heat_weights(hits, plans, weighting, threshold)
    assert weights.dtype == np.float32
    np.testing.assert_array_equal(weights.view(np.uint32), expected.view(np.uint32))
