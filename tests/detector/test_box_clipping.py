"""Rounding and clipping of refined boxes, and the box filter, on the few boxes of a frame.

Both run in plain Python per box (cheaper than NumPy on a handful of rows);
they must give what the vectorised NumPy rules give, halves rounded to even.
"""

from __future__ import annotations

import numpy as np
import pytest

from fastdet.detector.boxes import BoxFinder, _clipped
from fastdet.detector.config import BoxConfig, DetectorConfig


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
