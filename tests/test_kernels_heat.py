"""Tests for ``fastdet.kernels.heat`` against the naive per-box reference."""

from __future__ import annotations

import numpy as np
import pytest

from fastdet.kernels.heat import accumulate_heat, accumulate_heat_into
from naive import naive_heat


def assert_identical(actual, expected):
    # strict=True also checks shape and dtype instead of broadcasting.
    np.testing.assert_array_equal(actual, expected, strict=True)


def random_boxes(rng, n_boxes, height, width):
    """Boxes that mostly overlap the map but often stick out of it, plus
    degenerate ones (zero area, inverted, entirely outside)."""
    margin_x = max(width // 4, 2)
    margin_y = max(height // 4, 2)
    x1 = rng.integers(-margin_x, width + margin_x, n_boxes)
    y1 = rng.integers(-margin_y, height + margin_y, n_boxes)
    x2 = x1 + rng.integers(-2, width + 2 * margin_x, n_boxes)
    y2 = y1 + rng.integers(-2, height + 2 * margin_y, n_boxes)
    boxes = np.stack([x1, y1, x2, y2], axis=1).astype(np.int32)
    # Weights spanning a few orders of magnitude and both signs; within this
    # range float64 accumulation is exact, so results must match bit for bit.
    weights = (rng.uniform(0.01, 10.0, n_boxes) * rng.choice([-1, 1], n_boxes)).astype(
        np.float32
    )
    return boxes, weights


@pytest.mark.parametrize(
    ("height", "width", "n_boxes"),
    [(1, 1, 30), (7, 13, 40), (13, 7, 40), (64, 64, 200), (720, 1280, 300)],
)
@pytest.mark.parametrize("seed", [0, 1])
def test_matches_naive_random_boxes(height, width, n_boxes, seed):
    rng = np.random.default_rng(seed)
    boxes, weights = random_boxes(rng, n_boxes, height, width)
    heat = accumulate_heat(boxes, weights, height, width)
    assert_identical(heat, naive_heat(boxes, weights, height, width))
    # Guard against a vacuous pass: the random boxes must actually paint.
    assert np.count_nonzero(heat) > 0


def test_no_boxes_gives_zeros():
    boxes = np.zeros((0, 4), dtype=np.int32)
    weights = np.zeros(0, dtype=np.float32)
    assert_identical(accumulate_heat(boxes, weights, 7, 13), np.zeros((7, 13), np.float32))


@pytest.mark.parametrize(("height", "width"), [(0, 5), (5, 0), (0, 0)])
def test_empty_map(height, width):
    boxes = np.array([[0, 0, 3, 3]], dtype=np.int32)
    weights = np.ones(1, dtype=np.float32)
    assert_identical(
        accumulate_heat(boxes, weights, height, width), np.zeros((height, width), np.float32)
    )


def test_degenerate_and_outside_boxes_are_ignored():
    boxes = np.array(
        [
            [3, 3, 3, 6],  # zero width
            [3, 3, 6, 3],  # zero height
            [6, 6, 3, 3],  # inverted
            [-10, -10, 0, 5],  # ends exactly at the left edge
            [13, 0, 20, 7],  # starts exactly at the right edge
            [0, 7, 13, 9],  # starts exactly at the bottom edge
            [-5, -5, -1, -1],  # fully outside, negative
        ],
        dtype=np.int32,
    )
    weights = np.arange(1, len(boxes) + 1, dtype=np.float32)
    assert_identical(accumulate_heat(boxes, weights, 7, 13), np.zeros((7, 13), np.float32))


def test_known_layout_with_clipping():
    boxes = np.array([[-2, -1, 2, 2], [1, 1, 99, 99]], dtype=np.int32)
    weights = np.array([1.5, 0.25], dtype=np.float32)
    expected = np.array(
        [
            [1.5, 1.5, 0.0, 0.0],
            [1.5, 1.75, 0.25, 0.25],
            [0.0, 0.25, 0.25, 0.25],
        ],
        dtype=np.float32,
    )
    assert_identical(accumulate_heat(boxes, weights, 3, 4), expected)


def test_cancelling_weights_leave_exact_zero():
    # +w and -w on the same box must cancel to exactly 0.0 (no rounding
    # residue that would survive a `heat > 0` threshold) even with weights
    # that are not exactly representable in binary.
    rng = np.random.default_rng(3)
    boxes, weights = random_boxes(rng, 100, 50, 70)
    boxes = np.concatenate([boxes, boxes])
    weights = np.concatenate([weights, -weights])
    assert_identical(accumulate_heat(boxes, weights, 50, 70), np.zeros((50, 70), np.float32))


@pytest.mark.parametrize(("height", "width"), [(1, 1), (7, 13), (100, 37)])
def test_accumulate_into_adds_onto_existing(height, width):
    rng = np.random.default_rng(4)
    boxes, weights = random_boxes(rng, 30, height, width)
    existing = rng.normal(size=(height, width)).astype(np.float32)
    heat = existing.copy()
    result = accumulate_heat_into(heat, boxes, weights)
    assert result is None
    assert_identical(heat, existing + naive_heat(boxes, weights, height, width))
    # A second call keeps accumulating rather than overwriting.
    accumulate_heat_into(heat, boxes, weights)
    once = naive_heat(boxes, weights, height, width)
    assert_identical(heat, (existing + once) + once)


def test_accumulate_into_with_no_boxes_leaves_map_untouched():
    existing = np.random.default_rng(5).normal(size=(7, 13)).astype(np.float32)
    heat = existing.copy()
    accumulate_heat_into(heat, np.zeros((0, 4), np.int32), np.zeros(0, np.float32))
    assert_identical(heat, existing)


def test_mismatched_weights_raise():
    boxes = np.zeros((3, 4), dtype=np.int32)
    with pytest.raises(ValueError):
        accumulate_heat(boxes, np.ones(2, dtype=np.float32), 5, 5)
