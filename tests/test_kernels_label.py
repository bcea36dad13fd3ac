"""Tests for ``fastdet.kernels.label`` against ``scipy.ndimage`` and naive numpy."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.ndimage as ndi

from fastdet.kernels.label import (
    component_boxes,
    component_max,
    label_components,
    label_components_kernel,
)
from naive import naive_component_boxes, naive_component_max

STRUCTURES = {
    4: ndi.generate_binary_structure(2, 1),
    8: np.ones((3, 3), dtype=bool),
}
CONNECTIVITIES = [4, 8]
SHAPES = [(1, 1), (1, 40), (40, 1), (3, 5), (17, 31), (257, 129)]
DENSITIES = [0.05, 0.3, 0.45, 0.6, 0.8, 0.97]


def assert_identical(actual, expected):
    # strict=True also checks shape and dtype instead of broadcasting.
    np.testing.assert_array_equal(actual, expected, strict=True)


def assert_labels_match_scipy(mask, connectivity):
    labels, count = label_components(mask, connectivity)
    expected_labels, expected_count = ndi.label(mask, STRUCTURES[connectivity])
    assert isinstance(count, int)
    assert count == expected_count
    assert_identical(labels, expected_labels.astype(np.int32))
    return labels, count


def random_mask(shape, density, seed):
    return np.random.default_rng(seed).random(shape) < density


def spiral_mask(size):
    """One-pixel-wide clockwise square spiral with one-pixel gaps.

    Raster scanning meets its arms as many separate runs that only join far
    away, so labelling it forces long chains of merges.
    """
    mask = np.zeros((size, size), dtype=bool)
    y, x, dy, dx = 0, 0, 0, 1
    mask[y, x] = True
    length, legs = size - 1, 0
    while length > 0:
        for _ in range(length):
            y, x = y + dy, x + dx
            mask[y, x] = True
        dy, dx = dx, -dy  # turn clockwise
        legs += 1
        if legs >= 3 and legs % 2 == 1:
            length -= 2
    return mask


def comb_mask(height, width, teeth_up):
    """Vertical teeth on every other column joined by one horizontal bar at
    the bottom (a row of "U"s, needing one merge per tooth) or at the top."""
    mask = np.zeros((height, width), dtype=bool)
    mask[:, ::2] = True
    mask[-1 if teeth_up else 0, :] = True
    return mask


def nested_u_mask():
    return np.array(
        [
            [1, 0, 1, 0, 0, 1, 0, 1],
            [1, 0, 1, 0, 0, 1, 0, 1],
            [1, 0, 1, 1, 1, 1, 0, 1],
            [1, 0, 0, 0, 0, 0, 0, 1],
            [1, 1, 1, 1, 1, 1, 1, 1],
        ],
        dtype=bool,
    )


def checkerboard(height, width):
    return (np.indices((height, width)).sum(axis=0) % 2 == 0)


SPECIAL_MASKS = {
    "spiral_31": spiral_mask(31),
    "spiral_30_inverted": ~spiral_mask(30),
    "comb_up": comb_mask(9, 21, teeth_up=True),
    "comb_down": comb_mask(9, 21, teeth_up=False),
    "nested_u": nested_u_mask(),
    "diagonal": np.eye(9, 11, dtype=bool),
    "anti_diagonal": np.fliplr(np.eye(11, 9, dtype=bool)),
    "checkerboard_odd": checkerboard(9, 13),
    "checkerboard_even": checkerboard(8, 12),
    # Pixel whose only visited neighbours are up-left and up-right.
    "v_join": np.array([[1, 0, 1], [0, 1, 0]], dtype=bool),
    # Pixel whose only visited neighbours are up-right and left.
    "up_right_left_join": np.array([[0, 0, 1], [1, 1, 0]], dtype=bool),
    # Label numbering: component B's first pixel comes first in raster order
    # although component A is "bigger" and starts further left below.
    "raster_order": np.array(
        [[0, 0, 0, 1], [1, 0, 0, 1], [1, 1, 0, 0], [0, 1, 1, 1]], dtype=bool
    ),
}


@pytest.mark.parametrize("connectivity", CONNECTIVITIES)
@pytest.mark.parametrize("density", DENSITIES)
@pytest.mark.parametrize("shape", SHAPES, ids=lambda s: f"{s[0]}x{s[1]}")
def test_random_masks_match_scipy(shape, density, connectivity):
    seed = shape[0] * 1000 + shape[1] + int(density * 100)
    mask = random_mask(shape, density, seed)
    assert_labels_match_scipy(mask, connectivity)


@pytest.mark.parametrize("connectivity", CONNECTIVITIES)
def test_frame_sized_mask_matches_scipy(connectivity):
    assert_labels_match_scipy(random_mask((720, 1280), 0.1, seed=11), connectivity)


@pytest.mark.parametrize("connectivity", CONNECTIVITIES)
@pytest.mark.parametrize("name", list(SPECIAL_MASKS))
def test_special_shapes_match_scipy(name, connectivity):
    assert_labels_match_scipy(SPECIAL_MASKS[name], connectivity)


@pytest.mark.parametrize("connectivity", CONNECTIVITIES)
def test_spiral_is_one_component(connectivity):
    _, count = assert_labels_match_scipy(spiral_mask(31), connectivity)
    assert count == 1


def test_checkerboard_connectivity_differs():
    mask = checkerboard(9, 13)
    assert label_components(mask, 4)[1] == np.count_nonzero(mask)
    assert label_components(mask, 8)[1] == 1


@pytest.mark.parametrize("connectivity", CONNECTIVITIES)
@pytest.mark.parametrize("shape", [(0, 5), (5, 0), (0, 0)], ids=str)
def test_empty_mask(shape, connectivity):
    labels, count = label_components(np.zeros(shape, dtype=bool), connectivity)
    assert count == 0
    assert_identical(labels, np.zeros(shape, dtype=np.int32))


@pytest.mark.parametrize("connectivity", CONNECTIVITIES)
@pytest.mark.parametrize("shape", [(1, 1), (1, 7), (7, 1), (17, 31)], ids=str)
def test_all_false_and_all_true(shape, connectivity):
    labels, count = assert_labels_match_scipy(np.zeros(shape, dtype=bool), connectivity)
    assert count == 0
    labels, count = assert_labels_match_scipy(np.ones(shape, dtype=bool), connectivity)
    assert count == 1
    assert_identical(labels, np.ones(shape, dtype=np.int32))


@pytest.mark.parametrize("connectivity", CONNECTIVITIES)
def test_input_dtypes_and_layouts(connectivity):
    mask = random_mask((40, 60), 0.45, seed=7)
    expected = ndi.label(mask, STRUCTURES[connectivity])[0]
    variants = {
        "uint8_0_1": mask.astype(np.uint8),
        "uint8_0_255": mask.astype(np.uint8) * 255,
        "int64": mask.astype(np.int64) * -3,
        "float": mask * 0.5,
        "fortran": np.asfortranarray(mask),
        "list": mask.tolist(),
    }
    for name, variant in variants.items():
        labels, _ = label_components(variant, connectivity)
        np.testing.assert_array_equal(
            labels, expected.astype(np.int32), strict=True, err_msg=name
        )
    # A strided view must be labelled as the view, not its base.
    wide = random_mask((40, 120), 0.45, seed=8)
    view = wide[:, ::2]
    assert_identical(
        label_components(view, connectivity)[0],
        ndi.label(view, STRUCTURES[connectivity])[0].astype(np.int32),
    )


@pytest.mark.parametrize("connectivity", CONNECTIVITIES)
def test_kernel_matches_wrapper(connectivity):
    mask = random_mask((33, 47), 0.5, seed=9)
    labels, count = label_components_kernel(mask.view(np.uint8), connectivity == 8)
    expected_labels, expected_count = ndi.label(mask, STRUCTURES[connectivity])
    assert count == expected_count
    assert_identical(labels, expected_labels.astype(np.int32))


@pytest.mark.parametrize("connectivity", [0, 1, 6, 9, "8", None])
def test_invalid_connectivity_raises(connectivity):
    with pytest.raises(ValueError, match="connectivity"):
        label_components(np.ones((3, 3), dtype=bool), connectivity)


@pytest.mark.parametrize("shape", [(3,), (2, 3, 4)], ids=str)
def test_non_2d_mask_raises(shape):
    with pytest.raises(ValueError, match="2-D"):
        label_components(np.ones(shape, dtype=bool), 8)


def find_objects_boxes(labels, count):
    boxes = np.zeros((count, 4), dtype=np.int32)
    for k, slices in enumerate(ndi.find_objects(labels, max_label=count)):
        if slices is not None:
            rows, cols = slices
            boxes[k] = [cols.start, rows.start, cols.stop, rows.stop]
    return boxes


@pytest.mark.parametrize("connectivity", CONNECTIVITIES)
@pytest.mark.parametrize("density", [0.1, 0.45, 0.7])
@pytest.mark.parametrize("shape", [(1, 1), (1, 40), (40, 1), (17, 31), (257, 129)], ids=str)
def test_component_boxes(shape, density, connectivity):
    mask = random_mask(shape, density, seed=shape[0] + shape[1] + int(density * 10))
    labels, count = label_components(mask, connectivity)
    boxes = component_boxes(labels, count)
    expected = naive_component_boxes(labels, count)
    assert_identical(boxes, expected)
    assert_identical(boxes, find_objects_boxes(labels, count))


@pytest.mark.parametrize("name", ["spiral_31", "nested_u", "comb_up", "raster_order"])
def test_component_boxes_special_shapes(name):
    labels, count = label_components(SPECIAL_MASKS[name], 4)
    assert_identical(component_boxes(labels, count), naive_component_boxes(labels, count))


def test_component_boxes_known_values():
    labels = np.array(
        [
            [0, 1, 1, 0, 0],
            [0, 0, 1, 0, 2],
            [3, 0, 0, 0, 2],
        ],
        dtype=np.int32,
    )
    expected = np.array([[1, 0, 3, 2], [4, 1, 5, 3], [0, 2, 1, 3]], dtype=np.int32)
    assert_identical(component_boxes(labels, 3), expected)


def test_component_boxes_missing_and_out_of_range_labels():
    labels = np.array([[1, 0, 4], [0, 0, 4]], dtype=np.int32)
    # Labels 2 and 3 have no pixels; label 4 is beyond `count` and ignored.
    expected = np.array([[0, 0, 1, 1], [0, 0, 0, 0], [0, 0, 0, 0]], dtype=np.int32)
    assert_identical(component_boxes(labels, 3), expected)
    assert_identical(component_boxes(labels, 0), np.zeros((0, 4), dtype=np.int32))


@pytest.mark.parametrize("shape", [(0, 5), (5, 0)], ids=str)
def test_component_reductions_on_empty_input(shape):
    labels = np.zeros(shape, dtype=np.int32)
    values = np.zeros(shape, dtype=np.float32)
    assert_identical(component_boxes(labels, 0), np.zeros((0, 4), dtype=np.int32))
    assert_identical(component_max(labels, 0, values), np.zeros(0, dtype=np.float32))


@pytest.mark.parametrize("connectivity", CONNECTIVITIES)
@pytest.mark.parametrize("density", [0.1, 0.45, 0.7])
@pytest.mark.parametrize("shape", [(1, 1), (1, 40), (17, 31), (257, 129)], ids=str)
def test_component_max(shape, density, connectivity):
    rng = np.random.default_rng(shape[0] * 7 + shape[1] + int(density * 10))
    mask = rng.random(shape) < density
    values = rng.normal(size=shape).astype(np.float32)
    labels, count = label_components(mask, connectivity)
    maxima = component_max(labels, count, values)
    assert_identical(maxima, naive_component_max(labels, count, values))
    if count:
        indices = np.arange(1, count + 1)
        assert_identical(maxima, ndi.maximum(values, labels, indices).astype(np.float32))


def test_component_max_nan_missing_and_out_of_range():
    labels = np.array([[1, 1, 0, 2], [1, 0, 4, 2]], dtype=np.int32)
    values = np.array([[-5.0, np.nan, 100.0, -2.0], [7.0, 50.0, 99.0, -3.0]], np.float32)
    maxima = component_max(labels, 3, values)
    # Label 1 contains a NaN (propagates like numpy.max); label 3 is empty;
    # label 4 is beyond `count`; background 100.0 must not leak in.
    expected = np.array([np.nan, -2.0, -np.inf], dtype=np.float32)
    assert_identical(maxima, expected)
    assert_identical(maxima, naive_component_max(labels, 3, values))


@pytest.mark.parametrize("seed", range(5))
def test_component_core_boxes_match_numpy(seed):
    from fastdet.kernels.label import component_core_boxes

    rng = np.random.default_rng(seed)
    values = rng.random((41, 57)).astype(np.float32)
    labels, count = label_components(values > 0.4, 8)
    thresholds = rng.uniform(0.4, 1.0, count).astype(np.float32)
    boxes = component_core_boxes(labels, count, values, thresholds)
    for k in range(count):
        ys, xs = np.nonzero((labels == k + 1) & (values >= thresholds[k]))
        expected = [0, 0, 0, 0] if len(xs) == 0 else [xs.min(), ys.min(), xs.max() + 1, ys.max() + 1]
        assert boxes[k].tolist() == expected
