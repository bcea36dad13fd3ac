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


# -- heat blobs on the grid of constant cells ------------------------------------

from fastdet.kernels.label import constant_runs, heat_blobs, split_levels  # noqa: E402
from naive import naive_heat  # noqa: E402

SPLIT_FRACTIONS = np.linspace(0.2, 0.8, 5)


def reference_runs(bits):
    """Starts of the runs of identical rows / columns, with plain numpy."""
    height, width = bits.shape
    new_rows = np.ones(height, dtype=bool)
    new_rows[1:] = (bits[1:] != bits[:-1]).any(axis=1)
    new_cols = np.ones(width, dtype=bool)
    new_cols[1:] = (bits[:, 1:] != bits[:, :-1]).any(axis=0)
    return (np.append(np.flatnonzero(new_rows), height),
            np.append(np.flatnonzero(new_cols), width))


def box_heat(rng, height, width, n_boxes, step=1, dtype=np.float32):
    """A heat map of random boxes (edges on multiples of ``step``): piecewise constant."""
    x1 = rng.integers(-3, width, n_boxes) // step * step
    y1 = rng.integers(-3, height, n_boxes) // step * step
    x2 = x1 + rng.integers(1, max(2, width // 2), n_boxes) // step * step + step
    y2 = y1 + rng.integers(1, max(2, height // 2), n_boxes) // step * step + step
    boxes = np.stack([x1, y1, x2, y2], axis=1).astype(np.int32)
    weights = rng.uniform(0.2, 2.0, n_boxes).astype(np.float32)
    return naive_heat(boxes, weights, height, width).astype(dtype)


def two_humps(split=True):
    """Two car-sized heat humps joined by a low saddle, or nested into one hump (float32)."""
    heat = np.zeros((90, 220), np.float32)
    heat[15:85, 10:215] += 2.0
    heat[25:75, 20:100] += 3.0
    if split:
        heat[20:80, 120:210] += 4.0
    else:
        heat[30:70, 30:90] += 4.0
    return heat


@pytest.mark.parametrize("shape", [(1, 1), (1, 9), (9, 1), (17, 31), (120, 333)], ids=str)
@pytest.mark.parametrize("seed", range(3))
def test_constant_runs_match_numpy(shape, seed):
    rng = np.random.default_rng(seed * 7 + shape[1])
    heat = box_heat(rng, *shape, n_boxes=6, step=4)
    rows, cols = constant_runs(heat.view(np.uint32))
    expected_rows, expected_cols = reference_runs(heat.view(np.uint32))
    assert_identical(rows, expected_rows)
    assert_identical(cols, expected_cols)
    # The runs really are constant: every pixel equals its cell's first pixel.
    cell_rows = np.repeat(np.arange(len(rows) - 1), np.diff(rows))
    cell_cols = np.repeat(np.arange(len(cols) - 1), np.diff(cols))
    np.testing.assert_array_equal(
        heat, heat[rows[:-1]][:, cols[:-1]][np.ix_(cell_rows, cell_cols)])


def test_constant_runs_compare_bits():
    # -0.0 == 0.0 and NaN != NaN as floats, but runs go by identical bits.
    heat = np.array([[0.0, -0.0, np.nan, np.nan],
                     [0.0, -0.0, np.nan, np.nan],
                     [-0.0, -0.0, np.nan, np.nan]], dtype=np.float32)
    rows, cols = constant_runs(heat.view(np.uint32))
    assert rows.tolist() == [0, 2, 3]
    assert cols.tolist() == [0, 1, 2, 4]
    assert [r.tolist() for r in constant_runs(np.zeros((0, 3), np.uint32))] == [[0], [0, 3]]


@pytest.mark.parametrize("dtype, bits", [(np.float32, np.uint32), (np.float64, np.uint64)])
def test_constant_runs_of_floats_go_by_their_bits(dtype, bits):
    # heat_blobs passes the float map itself: the same runs as its bit view.
    heat = np.array([[0.0, -0.0, np.nan, np.nan, 1.0],
                     [0.0, -0.0, np.nan, np.nan, 1.0],
                     [-0.0, -0.0, np.nan, -np.nan, 1.0]], dtype=dtype)
    rows, cols = constant_runs(heat)
    expected_rows, expected_cols = reference_runs(heat.view(bits))
    assert_identical(rows, expected_rows)
    assert_identical(cols, expected_cols)
    assert rows.tolist() == [0, 2, 3]
    assert cols.tolist() == [0, 1, 2, 3, 4, 5]


@pytest.mark.parametrize("threshold", [3.0, 1.1, -0.5, 2.0 ** -30])
def test_split_levels_match_numpy(threshold):
    # heat_components' (threshold + (peak - threshold) * fractions) in NumPy 2
    # promotion: a float32 peak minus a Python float is float32.
    rng = np.random.default_rng(5)
    for peak in (rng.uniform(-2, 40, 200).astype(np.float32).tolist() + [threshold]):
        peak = np.float32(peak)
        expected = (threshold + (peak - threshold) * SPLIT_FRACTIONS).astype(np.float32)
        assert_identical(split_levels(peak, threshold, SPLIT_FRACTIONS), expected)


def reference_splits(values, mask, levels, min_size):
    """``split_component``'s decision with scipy: some level gives 2+ car-sized parts."""
    for level in levels:
        labels, count = ndi.label(mask & (values > level), STRUCTURES[8])
        if count == 0:
            return False
        big = sum(1 for rows, cols in ndi.find_objects(labels)
                  if cols.stop - cols.start >= min_size and rows.stop - rows.start >= min_size)
        if big >= 2:
            return True
    return False


def reference_blobs(heat, origin, threshold, connectivity, peak_fraction, split_size, step):
    """What ``heat_blobs`` returns, at full resolution with scipy and numpy.

    As the detector always did it: label the thresholded heat, take each
    blob's peak and (core) box, and probe blobs at least twice a car's size
    by ``split_component``'s decision on every ``step``-th pixel.
    """
    mask = heat > heat.dtype.type(threshold)
    empty = (np.zeros((0, 4), np.int32), np.zeros(0, np.float32), np.zeros(0, bool))
    if not mask.any():
        return empty
    y0 = np.flatnonzero(mask.any(axis=1))[0]
    x0 = np.flatnonzero(mask.any(axis=0))[0]
    labels, count = ndi.label(mask, STRUCTURES[connectivity])
    index = np.arange(1, count + 1)
    peaks = np.asarray(ndi.maximum(heat, labels, index)).astype(np.float32)
    whole = find_objects_boxes(labels, count)
    boxes = whole.copy()
    if peak_fraction > 0:
        core = (peaks * np.float32(peak_fraction)).astype(np.float32)
        for k in range(count):
            ys, xs = np.nonzero((labels == k + 1) & (heat >= core[k]))
            # An empty core box sits at the corner of the thresholded region.
            boxes[k] = ([x0, y0, x0, y0] if len(xs) == 0
                        else [xs.min(), ys.min(), xs.max() + 1, ys.max() + 1])
    probed = np.zeros(count, dtype=bool)
    for k in range(count if split_size >= 0 else 0):
        x1, y1, x2, y2 = whole[k]
        if max(x2 - x1, y2 - y1) < 2 * split_size:
            continue
        levels = (threshold + (peaks[k] - threshold) * SPLIT_FRACTIONS).astype(np.float32)
        region = heat[y1:y2:step, x1:x2:step]
        blob = (labels[y1:y2, x1:x2] == k + 1)[::step, ::step]
        probed[k] = reference_splits(region, blob, levels, max(1, split_size // step))
    boxes += np.array([origin[0], origin[1], origin[0], origin[1]], dtype=np.int32)
    return boxes, peaks, probed


def assert_blobs_match(heat, threshold=1.0, connectivity=8, peak_fraction=0.3, split_size=12,
                       step=4, origin=(5, -3)):
    expected = reference_blobs(heat, origin, threshold, connectivity, peak_fraction,
                               split_size, step)
    boxes, peaks, probed, n_probed = heat_blobs(
        heat, origin[0], origin[1], threshold, connectivity == 8, peak_fraction > 0,
        np.float32(peak_fraction), split_size, step, SPLIT_FRACTIONS)
    assert_identical(boxes, expected[0])
    assert_identical(peaks, expected[1])
    assert_identical(probed, expected[2])
    assert n_probed == expected[2].sum()
    return len(peaks), n_probed


@pytest.mark.parametrize("connectivity", CONNECTIVITIES)
@pytest.mark.parametrize("seed", range(24))
def test_heat_blobs_match_full_resolution(seed, connectivity):
    rng = np.random.default_rng(300 + seed)
    shape = [(90, 160), (37, 53), (64, 250)][seed % 3]
    heat = box_heat(rng, *shape, n_boxes=int(rng.integers(3, 30)), step=int(rng.choice([1, 3, 8])))
    count, _ = assert_blobs_match(heat, threshold=float(rng.uniform(0.5, 3.0)),
                                  connectivity=connectivity,
                                  peak_fraction=float(rng.choice([0.0, 0.3, 0.7])),
                                  split_size=int(rng.choice([-1, 4, 9, 16])),
                                  step=int(rng.choice([1, 2, 4])))


def test_heat_blobs_probe_both_ways():
    # The probe passes for two humps and fails for one; both decisions must
    # match the pixel-level probe.
    counts = [assert_blobs_match(two_humps(split), threshold=1.0, split_size=24, step=4)
              for split in (True, False)]
    assert counts == [(1, 1), (1, 0)]
    # Odd probe steps and sizes: samples straddle the cells unevenly.
    for step, size in [(3, 10), (5, 20), (7, 24), (1, 30), (4, 90)]:
        assert_blobs_match(two_humps(), threshold=1.0, split_size=size, step=step)
    # Probed because it is wide enough, although not tall enough (90 < 2 * 48).
    assert assert_blobs_match(two_humps(), threshold=1.0, split_size=48, step=4) == (1, 1)


def test_heat_blobs_probe_one_sample_parts():
    # Parts one probe sample wide count as cars when a car is one sample.
    heat = np.array([[0, 0, 0, 0, 0],
                     [0, 2, 1, 2, 0],
                     [0, 0, 0, 0, 0]], dtype=np.float32)
    assert assert_blobs_match(heat, threshold=0.5, split_size=1, step=1) == (1, 1)
    assert assert_blobs_match(heat, threshold=0.5, split_size=2, step=2) == (1, 0)


def test_heat_blobs_threshold_is_strict():
    # Heat exactly at the threshold is background, also in the split levels.
    heat = np.zeros((20, 30), np.float32)
    heat[2:18, 2:28] = 1.0
    heat[4:16, 4:12] = 2.0
    heat[4:16, 16:26] = 2.0
    assert assert_blobs_match(heat, threshold=1.0) == (2, 0)
    assert assert_blobs_match(heat, threshold=0.0, split_size=4, step=2, peak_fraction=0.5) == (1, 1)
    # Peaks 10 and 6 joined by a saddle at exactly the level 0 + 10 * 0.5:
    # only that level separates them, and only because the test is strict.
    heat = np.zeros((12, 40), np.float32)
    heat[2:10, 2:38] = 5.0
    heat[2:10, 2:12] = 10.0
    heat[2:10, 28:38] = 6.0
    assert assert_blobs_match(heat, threshold=0.0, split_size=4, step=1) == (1, 1)


@pytest.mark.parametrize("connectivity", CONNECTIVITIES)
def test_heat_blobs_on_heat_that_is_not_piecewise_constant(connectivity):
    # No runs to merge: every pixel is its own cell.
    rng = np.random.default_rng(8)
    heat = ndi.uniform_filter(rng.random((60, 90)).astype(np.float32), 5)
    count, _ = assert_blobs_match(heat, threshold=0.5, connectivity=connectivity,
                                  split_size=6, step=2)
    assert count > 1


def test_heat_blobs_float64_and_strided_heat():
    rng = np.random.default_rng(9)
    heat = box_heat(rng, 80, 120, 20, step=4, dtype=np.float64) * 1.01
    assert_blobs_match(heat, threshold=1.3)
    wide = np.repeat(box_heat(rng, 80, 120, 20, step=4), 2, axis=1)
    assert_blobs_match(wide[:, ::2], threshold=1.3)
    # Threshold and peak-fraction rounding: compared in the heat's precision.
    heat32 = np.full((5, 5), np.float32(0.1))
    assert assert_blobs_match(heat32, threshold=0.1)[0] == 0
    assert assert_blobs_match(heat32.astype(np.float64), threshold=0.1)[0] == 1


def test_heat_blobs_edge_cases():
    # Nothing above the threshold; a single pixel; everything above.
    assert assert_blobs_match(np.zeros((7, 9), np.float32)) == (0, 0)
    assert assert_blobs_match(np.full((1, 1), 5.0, np.float32)) == (1, 0)
    assert assert_blobs_match(np.full((30, 40), 5.0, np.float32), split_size=10) == (1, 0)
    # Negative threshold and peaks: empty core boxes at the region's corner.
    heat = np.full((6, 8), -0.2, np.float32)
    heat[2:4, 3:6] = -0.1
    heat[0, 0] = -1.0
    count, _ = assert_blobs_match(heat, threshold=-0.5, peak_fraction=0.5)
    assert count == 1
