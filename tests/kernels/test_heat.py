"""Tests for ``fastdet.kernels.heat`` against the naive per-box reference."""

from __future__ import annotations

import numpy as np
import pytest

from fastdet.kernels.heat import accumulate_heat, accumulate_heat_into, decay_heat
from naive import naive_heat, naive_windows_above


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
    existing[::2, ::3] = -0.0  # even -0.0 stays (adding 0.0 would flip it)
    heat = existing.copy()
    accumulate_heat_into(heat, np.zeros((0, 4), np.int32), np.zeros(0, np.float32))
    np.testing.assert_array_equal(heat.view(np.uint32), existing.view(np.uint32))


def test_mismatched_weights_raise():
    boxes = np.zeros((3, 4), dtype=np.int32)
    with pytest.raises(ValueError):
        accumulate_heat(boxes, np.ones(2, dtype=np.float32), 5, 5)


# -- the cell grid ---------------------------------------------------------------

from fastdet.kernels.heat import box_heat_region, heat_cells, windows_above  # noqa: E402


def assert_same_bits(actual, expected):
    """Identical shape, dtype and bits (so -0.0 != 0.0 and NaN payloads count)."""
    assert_identical(actual, expected)
    np.testing.assert_array_equal(actual.view(np.uint32), expected.view(np.uint32))


def difference_array_heat(boxes, weights, height, width):
    """The plain full-resolution difference-array method, in numpy.

    ``np.cumsum`` adds sequentially, so this performs exactly the additions
    of a row-then-column running-sum pass, in the same order: the kernels
    must match it bit for bit even where float64 rounds.
    """
    diff = np.zeros((height + 1, width + 1), dtype=np.float64)
    for (x1, y1, x2, y2), weight in zip(np.asarray(boxes).tolist(), weights):
        x1, x2 = np.clip([x1, x2], 0, width)
        y1, y2 = np.clip([y1, y2], 0, height)
        if x2 > x1 and y2 > y1:
            weight = np.float64(weight)
            diff[y1, x1] += weight
            diff[y1, x2] -= weight
            diff[y2, x1] -= weight
            diff[y2, x2] += weight
    summed = np.cumsum(np.cumsum(diff, axis=1), axis=0)
    return summed[:height, :width].astype(np.float32)


@pytest.mark.parametrize("seed", range(4))
def test_bit_identical_to_full_resolution_method_when_float64_rounds(seed):
    # Huge weights of both signs that cancel over tiny ones: the float64
    # running sums round, so only the same additions in the same order give
    # the same bits (a per-box accumulation does not).
    rng = np.random.default_rng(100 + seed)
    height, width = 61, 83
    boxes, small = random_boxes(rng, 300, height, width)
    huge = np.float32(3e7) * rng.choice([1, -1], len(boxes)).astype(np.float32)
    weights = np.where(np.arange(len(boxes)) % 3 == 0, small * np.float32(1e-4), huge)
    expected = difference_array_heat(boxes, weights, height, width)
    assert not np.array_equal(expected, naive_heat(boxes, weights, height, width))
    assert_same_bits(accumulate_heat(boxes, weights, height, width), expected)
    heat = np.zeros((height, width), np.float32)
    accumulate_heat_into(heat, boxes, weights)
    assert_same_bits(heat, expected)


def test_window_grid_boxes_match_naive():
    # Many boxes sharing edges, like a detector's window grid (8-px steps).
    rng = np.random.default_rng(6)
    xs, ys = np.meshgrid(np.arange(0, 400, 8), np.arange(0, 120, 8))
    starts = np.stack([xs.ravel(), ys.ravel()], axis=1)
    chosen = starts[rng.random(len(starts)) < 0.2]
    side = rng.choice([32, 48, 64], len(chosen))
    boxes = np.column_stack([chosen, chosen + side[:, None]]).astype(np.int32)
    weights = rng.uniform(0.01, 3.0, len(boxes)).astype(np.float32)
    assert_same_bits(accumulate_heat(boxes, weights, 150, 430),
                     naive_heat(boxes, weights, 150, 430))


@pytest.mark.parametrize(("height", "width", "n_boxes"), [(1, 1, 5), (7, 13, 20), (90, 70, 60)])
def test_heat_cells_expand_to_the_heat_map(height, width, n_boxes):
    rng = np.random.default_rng(height + width)
    boxes, weights = random_boxes(rng, n_boxes, height, width)
    x0, y0 = 3, -2
    shifted = boxes + np.array([x0, y0, x0, y0], dtype=np.int32)
    rows, cols, cells = heat_cells(shifted, weights, x0, y0, height, width)
    assert rows[0] == 0 and rows[-1] == height and np.all(np.diff(rows) > 0)
    assert cols[0] == 0 and cols[-1] == width and np.all(np.diff(cols) > 0)
    expanded = np.repeat(np.repeat(cells, np.diff(rows), axis=0), np.diff(cols), axis=1)
    assert_same_bits(expanded, naive_heat(boxes, weights, height, width))
    # Cells are cut only at (clipped) edges of boxes that paint something.
    clipped = np.clip(boxes, 0, [width, height, width, height])
    painting = (clipped[:, 2] > clipped[:, 0]) & (clipped[:, 3] > clipped[:, 1])
    assert set(cols[1:-1]) <= set(clipped[painting][:, [0, 2]].ravel())
    assert set(rows[1:-1]) <= set(clipped[painting][:, [1, 3]].ravel())


def test_heat_cells_without_boxes_is_one_zero_cell():
    rows, cols, cells = heat_cells(np.zeros((0, 4), np.int32), np.zeros(0, np.float32),
                                   0, 0, 4, 6)
    assert rows.tolist() == [0, 4] and cols.tolist() == [0, 6]
    assert_same_bits(cells, np.zeros((1, 1), np.float32))


def test_accumulate_into_negative_zero_becomes_zero_where_uncovered():
    # heat += 0.0 turns -0.0 into +0.0, as numpy's addition does.
    boxes = np.array([[1, 1, 3, 2]], dtype=np.int32)
    weights = np.array([2.5], dtype=np.float32)
    heat = np.full((3, 4), -0.0, dtype=np.float32)
    accumulate_heat_into(heat, boxes, weights)
    assert_same_bits(heat, np.full((3, 4), -0.0, np.float32) + naive_heat(boxes, weights, 3, 4))


def reference_region(boxes, weights, width, height):
    x0 = max(int(boxes[:, 0].min()), 0)
    y0 = max(int(boxes[:, 1].min()), 0)
    x1 = min(int(boxes[:, 2].max()), width)
    y1 = min(int(boxes[:, 3].max()), height)
    shifted = boxes - np.array([x0, y0, x0, y0])
    return naive_heat(shifted, weights, y1 - y0, x1 - x0), x0, y0


@pytest.mark.parametrize("seed", range(6))
def test_box_heat_region_matches_numpy(seed):
    rng = np.random.default_rng(200 + seed)
    width, height = 320, 180
    n_boxes = int(rng.integers(1, 40))
    x1 = rng.integers(-40, width, n_boxes)
    y1 = rng.integers(-40, height, n_boxes)
    side = rng.integers(1, 90, n_boxes)
    boxes = np.stack([x1, y1, x1 + side, y1 + side], axis=1).astype(np.int32)
    weights = rng.uniform(0.1, 4.0, n_boxes).astype(np.float32)
    heat, x0, y0 = box_heat_region(boxes, weights, width, height)
    expected, ex0, ey0 = reference_region(boxes, weights, width, height)
    assert (x0, y0) == (ex0, ey0)
    assert_same_bits(heat, expected)
    assert np.count_nonzero(heat) > 0


def test_box_heat_region_edge_cases():
    empty, x0, y0 = box_heat_region(np.zeros((0, 4), np.int32), np.zeros(0, np.float32), 9, 9)
    assert_identical(empty, np.zeros((0, 0), np.float32))
    assert (x0, y0) == (0, 0)
    # One box touching the frame's far corner, one pixel.
    heat, x0, y0 = box_heat_region(np.array([[8, 6, 12, 20]], np.int32),
                                   np.array([1.5], np.float32), 9, 7)
    assert (x0, y0) == (8, 6)
    assert_same_bits(heat, np.full((1, 1), 1.5, np.float32))
    with pytest.raises(ValueError):
        box_heat_region(np.array([[20, 0, 30, 5]], np.int32), np.ones(1, np.float32), 9, 9)
    with pytest.raises(ValueError):
        box_heat_region(np.zeros((2, 4), np.int32), np.ones(3, np.float32), 9, 9)


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("n_windows", [0, 1, 7, 815])
def test_windows_above_matches_numpy(seed, n_windows):
    rng = np.random.default_rng(300 + seed)
    scores = rng.normal(-1.0, 1.5, n_windows).astype(np.float32)
    # Scores on the threshold and one float32 step either side of it.
    threshold = float(rng.choice([-0.5, 0.1, 1.3]))
    near = np.float32(threshold)
    picks = rng.integers(0, max(n_windows, 1), min(n_windows, 6))
    scores[picks[:2]] = near
    scores[picks[2:4]] = np.nextafter(near, np.float32(np.inf))
    scores[picks[4:]] = np.nextafter(near, np.float32(-np.inf))
    boxes = rng.integers(-50, 1300, (n_windows, 4)).astype(np.int32)
    scale_index = rng.integers(0, 5, n_windows).astype(np.int64)
    got = windows_above(scores, np.float32(threshold), boxes, scale_index)
    expected = naive_windows_above(scores, threshold, boxes, scale_index)
    for mine, theirs in zip(got, expected):
        assert_identical(mine, theirs)
    assert got[0].flags.c_contiguous


def test_windows_above_threshold_in_float32():
    # 0.1 is not a float32: the comparison is with float32(0.1), as NumPy's.
    scores = np.array([np.float32(0.1), np.nextafter(np.float32(0.1), np.float32(1))],
                      np.float32)
    boxes = np.arange(8, dtype=np.int32).reshape(2, 4)
    got_boxes, got_scores, got_scales = windows_above(scores, np.float32(0.1), boxes,
                                                      np.arange(2, dtype=np.int64))
    assert_identical(got_boxes, boxes[1:])
    assert_identical(got_scales, np.array([1], np.int64))
    assert (scores > 0.1).tolist() == [False, True]


def test_windows_above_refuses_mismatched_rows():
    with pytest.raises(ValueError):
        windows_above(np.zeros(3, np.float32), np.float32(0), np.zeros((2, 4), np.int32),
                      np.zeros(3, np.int64))
    with pytest.raises(ValueError):
        windows_above(np.zeros(2, np.float32), np.float32(0), np.zeros((2, 4), np.int32),
                      np.zeros(3, np.int64))


@pytest.mark.parametrize("shape, region, offset", [
    ((1, 1), (1, 1), (0, 0)), ((7, 13), (3, 5), (4, 2)), ((194, 1280), (150, 900), (17, 33)),
    ((9, 11), (9, 11), (0, 0)), ((9, 11), (0, 0), (3, 3))])
def test_decay_heat_rounds_as_numpy(shape, region, offset):
    rng = np.random.default_rng(shape[1])
    state = (rng.random(shape) * 7).astype(np.float32)
    heat = (rng.random(region) * 5).astype(np.float32)
    x0, y0 = offset
    keep, weight = np.float32(0.75), np.float32(0.25)
    expected = state.copy()
    expected *= keep
    expected[y0:y0 + region[0], x0:x0 + region[1]] += weight * heat
    decay_heat(state, heat, x0, y0, keep, weight)
    np.testing.assert_array_equal(state, expected)


@pytest.mark.parametrize("offset", [(-1, 0), (0, -1), (5, 0), (0, 5)])
def test_decay_heat_refuses_a_region_outside_the_map(offset):
    with pytest.raises(ValueError, match="inside the map"):
        decay_heat(np.zeros((6, 8), np.float32), np.ones((2, 4), np.float32), *offset,
                   np.float32(0.5), np.float32(0.5))
