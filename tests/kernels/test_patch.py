"""Tests for ``fastdet.kernels.patch`` against OpenCV and naive numpy."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from fastdet.kernels.patch import (
    grey_thumbnail,
    mask_overlap_search,
    saturation_mask,
    sum_squared_difference,
)


def every_colour(step=3):
    values = np.arange(0, 256, step)
    grid = np.stack(np.meshgrid(values, values, values, indexing="ij"), axis=-1)
    return np.ascontiguousarray(grid.reshape(-1, 1, 3).astype(np.uint8))


@pytest.mark.parametrize("threshold", [0, 1, 50, 100, 101, 200, 254])
def test_saturation_mask_matches_opencv_hsv(threshold):
    image = every_colour()
    expected = cv2.cvtColor(image, cv2.COLOR_BGR2HSV)[..., 1] > threshold
    np.testing.assert_array_equal(saturation_mask(image, threshold), expected.astype(np.uint8))


def naive_search(reference, candidate, centre, radius):
    h, w = reference.shape
    best = (-1.0, 0, -1, -1)
    last_y = min(centre[0] + radius, candidate.shape[0] - h)
    for oy in range(max(centre[0] - radius, 0), last_y + 1):
        for ox in range(max(centre[1] - radius, 0),
                        min(centre[1] + radius, candidate.shape[1] - w) + 1):
            window = candidate[oy:oy + h, ox:ox + w].astype(bool)
            ref = reference.astype(bool)
            union = (ref | window).sum()
            iou = (ref & window).sum() / union if union else 0.0
            distance = (oy - centre[0]) ** 2 + (ox - centre[1]) ** 2
            if iou > best[0] or (iou == best[0] and distance < best[1]):
                best = (iou, distance, oy, ox)
    return best[2], best[3], best[0]


def blob(height, width, seed):
    """A smooth random blob, like a vehicle's saturated region."""
    rng = np.random.default_rng(seed)
    noise = cv2.GaussianBlur(rng.random((height, width)).astype(np.float32), (0, 0), 4)
    return (noise > np.median(noise)).astype(np.uint8)


@pytest.mark.parametrize("width", [7, 64, 65, 130])  # one word, exactly one, two, three
def test_dense_search_matches_naive_iou(width):
    rng = np.random.default_rng(width)
    reference = (rng.random((11, width)) < 0.5).astype(np.uint8)
    candidate = (rng.random((11 + 14, width + 14)) < 0.5).astype(np.uint8)
    candidate[9:20, 3:3 + width] = reference
    centre = (7, 7)
    got = mask_overlap_search(reference, candidate, centre, 7, 1)
    expected = naive_search(reference, candidate, centre, 7)
    assert got[:2] == expected[:2] == (9, 3)
    assert got[2] == pytest.approx(expected[2]) == 1.0


def test_coarse_to_fine_search_finds_a_smooth_blob_at_odd_offsets():
    reference = blob(40, 90, seed=0)
    candidate = np.zeros((40 + 32, 90 + 32), np.uint8)
    candidate[13:53, 21:111] = reference
    assert mask_overlap_search(reference, candidate, (16, 16), 16, 2) == (13, 21, 1.0)


def test_search_scores_partial_overlap_like_naive():
    reference = blob(30, 50, seed=1)
    rng = np.random.default_rng(2)
    candidate = (rng.random((50, 70)) < 0.3).astype(np.uint8)
    got = mask_overlap_search(reference, candidate, (10, 10), 10, 1)
    expected = naive_search(reference, candidate, (10, 10), 10)
    assert got[:2] == expected[:2]
    assert got[2] == pytest.approx(expected[2])


def test_search_prefers_the_centre_on_ties_and_handles_degenerate_input():
    ones = np.ones((5, 5), np.uint8)
    assert mask_overlap_search(ones, np.ones((15, 15), np.uint8), (4, 6), 5, 2) == (4, 6, 1.0)
    assert mask_overlap_search(np.zeros((5, 5), np.uint8), np.zeros((9, 9), np.uint8),
                               (2, 2), 2, 1) == (2, 2, 0.0)
    assert mask_overlap_search(ones, np.ones((4, 9), np.uint8), (0, 0), 2, 1) == (-1, -1, 0.0)


def test_grey_thumbnail_is_the_block_mean():
    rng = np.random.default_rng(3)
    image = rng.integers(0, 256, (37, 50, 3)).astype(np.uint8)
    grey = image[:36, :48].astype(np.float64).mean(axis=2)
    expected = grey.reshape(9, 4, 12, 4).mean(axis=(1, 3))
    np.testing.assert_allclose(grey_thumbnail(image, 4), expected, rtol=1e-6)
    assert grey_thumbnail(image, 1).shape == (37, 50)
    white = np.full((256, 300, 3), 255, np.uint8)   # the largest block sums do not overflow
    np.testing.assert_array_equal(grey_thumbnail(white, 256), [[255.0]])


def test_sum_squared_difference():
    a = np.array([[1, 2], [3, 4]], np.float32)
    b = np.array([[1, 0], [0, 4]], np.float32)
    assert sum_squared_difference(a, b) == 13.0
