"""Tests for ``fastdet.kernels.refine`` against the NumPy reference in naive.py."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import fastdet
from fastdet.detector.refine import LEVELS, N_FEATURES
from fastdet.kernels.refine import box_heat_features, refined_edges, snap_box_sides
from naive import naive_heat_features, naive_refine_boxes, naive_snap_box_sides


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


# -- snap_box_sides -----------------------------------------------------------
def kernel_snap(frame, boxes, fraction, limits):
    boxes = np.ascontiguousarray(np.asarray(boxes, np.int64).reshape(-1, 4))
    out = np.full((len(boxes), 4), -99, np.int64)
    snap_box_sides(np.ascontiguousarray(frame), boxes, fraction, np.array(limits, np.int64), out)
    return out


@pytest.mark.parametrize("fraction", [0.0, 0.05, 0.1, 0.3])
@pytest.mark.parametrize("shape", [(3, 3), (5, 41), (37, 53), (64, 129)])
@pytest.mark.parametrize("seed", range(3))
def test_snapped_sides_match_scipy_sobel(fraction, shape, seed):
    rng = np.random.default_rng(seed)
    height, width = shape
    frame = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
    # Boxes around, across and outside the frame, limits inside and beyond it.
    x1 = rng.integers(-5, width, 12)
    y1 = rng.integers(-5, height, 12)
    boxes = np.stack([x1, y1, x1 + rng.integers(1, width + 5, 12),
                      y1 + rng.integers(1, height + 5, 12)], axis=1)
    for limits in ((0, 0, width, height), (-3, -3, width + 3, height + 3),
                   (width // 4, height // 3, width - width // 5, height - 1)):
        got = kernel_snap(frame, boxes, fraction, limits)
        np.testing.assert_array_equal(got, naive_snap_box_sides(frame, boxes, fraction, limits))


def test_sides_snap_to_a_car_like_block_within_reach():
    frame = np.full((60, 120, 3), 90, np.uint8)
    frame[20:50, 40:81] = 200          # a bright body: edges after columns 39 and 80
    frame[:, 100] = 255                # a pole beyond the reach
    got = kernel_snap(frame, [[36, 18, 84, 52], [47, 18, 78, 52], [0, 0, 1, 60],
                              [10, 18, 30, 52]], 0.1, (0, 0, 120, 60))
    # The strongest columns are 39 and 40 (the first of equals: 39) and 80 and
    # 81 (80, so x2 = 81).  Within reach of 47 (3 columns) the body is flat: no
    # edge, no move.  A box one column wide, or on flat ground, stays.
    assert got.tolist() == [[39, 18, 81, 52], [47, 18, 81, 52], [0, 0, 1, 60],
                            [10, 18, 30, 52]]


def test_snapping_reads_only_inside_the_limits():
    rng = np.random.default_rng(5)
    frame = rng.integers(0, 256, (80, 100, 3), dtype=np.uint8)
    boxes = [[10, -40, 60, 120], [40, -20, 95, 100]]   # middle halves beyond the limits
    limits = (0, 20, 100, 64)
    expected = kernel_snap(frame, boxes, 0.2, limits)
    noisy = frame.copy()
    noisy[:20] = rng.integers(0, 256, noisy[:20].shape, dtype=np.uint8)
    noisy[64:] = rng.integers(0, 256, noisy[64:].shape, dtype=np.uint8)
    np.testing.assert_array_equal(kernel_snap(noisy, boxes, 0.2, limits), expected)
    # Without the limits the same noise moves them.
    assert not np.array_equal(kernel_snap(noisy, boxes, 0.2, (0, 0, 100, 80)),
                              kernel_snap(frame, boxes, 0.2, (0, 0, 100, 80)))
