"""Tests for ``fastdet.kernels.refine`` against the NumPy reference in naive.py."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import fastdet
from fastdet.detector.refine import LEVELS, N_FEATURES
from fastdet.kernels.refine import box_heat_features, refined_edges
from naive import naive_heat_features, naive_refine_boxes


def kernel_features(heat, origin, boxes, threshold, frame_size, levels=LEVELS):
    boxes = np.ascontiguousarray(np.asarray(boxes, np.int64).reshape(-1, 4))
    out = np.full((len(boxes), 1 + 4 * len(levels) + 6), np.nan)
    box_heat_features(heat, origin[0], origin[1], boxes, threshold, frame_size[0], frame_size[1],
                      np.array(levels, np.float64), out)
    return out


def random_boxes(rng, count, origin, shape):
    """Boxes around, inside, across and outside a heat region, odd sizes included."""
    ox, oy = origin
    h, w = shape
    x1 = rng.integers(ox - 10, ox + w + 5, count)
    y1 = rng.integers(oy - 10, oy + h + 5, count)
    return np.stack([x1, y1, x1 + rng.integers(1, w + 10, count),
                     y1 + rng.integers(1, h + 10, count)], axis=1)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("shape", [(1, 1), (1, 17), (13, 1), (37, 53), (64, 129)])
@pytest.mark.parametrize("seed", range(3))
def test_random_heat_matches_numpy(dtype, shape, seed):
    rng = np.random.default_rng(seed)
    # Piecewise-constant plateaus (as box heat is) over noise, some of it below the threshold.
    heat = rng.uniform(0, 3, shape)
    for _ in range(4):
        y, x = rng.integers(0, shape[0]), rng.integers(0, shape[1])
        heat[y:y + rng.integers(1, 20), x:x + rng.integers(1, 30)] += rng.uniform(1, 6)
    heat = heat.astype(dtype)
    origin = (int(rng.integers(0, 400)), int(rng.integers(0, 300)))
    boxes = random_boxes(rng, 25, origin, shape)
    for frame_size in ((origin[0] * 2 + 40, 720), (1280, 720), (31, 17)):
        got = kernel_features(heat, origin, boxes, 1.5, frame_size)
        want = naive_heat_features(heat, origin, boxes, 1.5, frame_size, LEVELS)
        # Sums in another order: equal to float64 rounding.
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)


def test_levels_and_the_flat_fallback():
    heat = np.zeros((20, 30), np.float32)
    heat[5:15, 4:10] = 2.0
    heat[8:12, 6:8] = 5.0
    boxes = np.array([[0, 0, 30, 20], [20, 0, 30, 20], [-50, -50, -10, -10]])
    for levels in ((0.5,), (0.1, 0.5, 0.9)):
        got = kernel_features(heat, (0, 0), boxes, 1.0, (60, 40), levels)
        np.testing.assert_allclose(got, naive_heat_features(heat, (0, 0), boxes, 1.0, (60, 40),
                                                             levels), rtol=1e-12, atol=1e-12)
    # Box 2 holds no heat above the threshold and box 3 none at all: flat-blob features.
    flat = [-0.5, -0.5, 0.5, 0.5] * 3 + [0.0, 0.0, 0.29, 0.29]
    np.testing.assert_array_equal(got[1:, 1:-2], [flat, flat])


def test_a_detected_frame_matches_numpy(data_dir):
    frame = cv2.imread(str(data_dir / "test_images" / "test1.jpg"))
    detector = fastdet.Detector()
    size = (frame.shape[1], frame.shape[0])
    heat, origin = detector.heat_region(detector.hits(frame), size)
    boxes, _ = detector.box_finder.heat_components(heat, origin, size)
    assert len(boxes) >= 2
    threshold = detector.config.heat.threshold
    got = kernel_features(heat, origin, boxes, threshold, size)
    assert got.shape == (len(boxes), N_FEATURES)
    np.testing.assert_allclose(got, naive_heat_features(heat, origin, boxes, threshold, size),
                               rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("seed", range(4))
def test_refined_edges_match_numpy(seed):
    rng = np.random.default_rng(seed)
    count = 40
    boxes = random_boxes(rng, count, (0, 0), (300, 500))
    features = rng.normal(0, 1, (count, N_FEATURES))
    weights = rng.normal(0, 0.3, (4, N_FEATURES))
    # One frame width for all, and one per box (as training passes them).
    for frame_width in (500, rng.integers(1, 1000, count).astype(np.float64)):
        widths = np.broadcast_to(np.asarray(frame_width, np.float64), count).copy()
        out = np.full((count, 4), np.nan)
        refined_edges(np.ascontiguousarray(boxes, np.int64), features, weights, widths, out)
        want = naive_refine_boxes(boxes, features, weights, frame_width)
        np.testing.assert_allclose(out, want, rtol=1e-12, atol=1e-9)
        # Edges the model crossed were put back in order.
        assert (out[:, 2] >= out[:, 0]).all() and (out[:, 3] >= out[:, 1]).all()
