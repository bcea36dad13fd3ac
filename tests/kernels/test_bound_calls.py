"""The kernels' bound calls give what their functions give.

``PhaseCellRows``, ``ColourMapRows`` and ``RowResizer`` check their arrays
and work out their sizes once, for the detector, which calls them on every
scale of every frame; whatever rows they are asked for, the results must be
those of ``cell_histograms``, ``colour_maps`` and ``resize_linear`` (which
the kernel tests check against the naive references and OpenCV), and
``resize_linear`` must stay bit-identical to OpenCV through them.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from fastdet.kernels.colour import ColourMapRows, colour_maps
from fastdet.kernels.hog import PhaseCellRows, cell_histograms, phase_layout_shape
from fastdet.kernels.resize import RowResizer, resize_linear


def bands(length, step):
    """Row bands covering ``0 .. length`` in steps, and the whole."""
    cuts = list(range(0, length, step)) + [length]
    return [(0, length)] + list(zip(cuts[:-1], cuts[1:]))


@pytest.mark.parametrize("shape, ppc, nbins", [
    ((64, 200, 3), (8, 8), 9),     # the fast path
    ((77, 131, 3), (8, 8), 9),     # odd sizes: partial cells dropped
    ((48, 40, 1), (8, 8), 9),
    ((45, 77, 2), (6, 5), 7),      # the general path
])
@pytest.mark.parametrize("step, pad", [(1, 0), (2, 19), (3, 5)])
def test_phase_cell_rows_match_cell_histograms(shape, ppc, nbins, step, pad):
    rng = np.random.default_rng(shape[0] + step)
    image = rng.integers(0, 256, shape, dtype=np.uint8)
    expected = cell_histograms(image, ppc, nbins, phase_step=step, phase_pad=pad)
    cells_y, cells_x = shape[0] // ppc[0], shape[1] // ppc[1]
    out = np.zeros(phase_layout_shape(cells_y, cells_x, shape[2], nbins, step, pad), np.float32)
    rows = PhaseCellRows(shape, ppc, nbins, out, step, pad)
    assert rows.out is out
    for first, stop in bands(cells_y, 3):
        out[...] = 0.0
        rows(image, first, stop)
        np.testing.assert_array_equal(out[first:stop], expected[first:stop])
        assert not out[:first].any() and not out[stop:].any()


def test_phase_cell_rows_check_their_image_and_array():
    out = np.zeros(phase_layout_shape(4, 4, 3, 9, 2, 3), np.float32)
    rows = PhaseCellRows((32, 32, 3), (8, 8), 9, out, 2, 3)
    with pytest.raises(ValueError, match="shape"):
        rows(np.zeros((32, 40, 3), np.uint8), 0, 4)
    with pytest.raises(ValueError, match="uint8"):
        rows(np.zeros((32, 32, 3), np.float32), 0, 4)
    with pytest.raises(ValueError, match="C-contiguous"):
        rows(np.zeros((32, 64, 3), np.uint8)[:, ::2], 0, 4)
    with pytest.raises(ValueError, match="out must be"):
        PhaseCellRows((32, 32, 3), (8, 8), 9, np.zeros((4, 3, 9, 8), np.float32), 2, 3)


@pytest.mark.parametrize("shape, tile, factor, with_lut", [
    ((64, 128, 3), 16, 2, True),    # the detector's tiles and boxes
    ((64, 128, 3), 16, 2, False),   # boxes only
    ((96, 72, 3), 8, 4, True),
    ((96, 72, 3), 8, 4, False),
    ((48, 40, 3), 16, 0, True),     # tiles only
])
def test_colour_map_rows_match_colour_maps(shape, tile, factor, with_lut):
    rng = np.random.default_rng(shape[1] + tile)
    image = rng.integers(0, 256, shape, dtype=np.uint8)
    lut = rng.normal(size=(3, 256)).astype(np.float32) if with_lut else None
    expected_tiles, expected_box = colour_maps(image, lut, tile, factor)
    tiles = np.full(expected_tiles.shape, np.nan, np.float32)
    box = np.full(expected_box.shape, np.nan, np.float32)
    rows = ColourMapRows(shape, lut, tile, factor, (tiles, box))
    align = int(np.lcm(tile, max(factor, 1)))
    for top, bottom in bands(shape[0], 2 * align):
        tiles[...] = np.nan
        box[...] = np.nan
        rows(image, top, bottom)
        if lut is not None:
            np.testing.assert_array_equal(tiles[top // tile:bottom // tile],
                                          expected_tiles[top // tile:bottom // tile])
        if factor:
            np.testing.assert_array_equal(box[top // factor:bottom // factor],
                                          expected_box[top // factor:bottom // factor])


def test_colour_map_rows_refuse_rows_that_cut_tiles():
    tiles = np.zeros((4, 8), np.float32)
    box = np.zeros((32, 64, 3), np.float32)
    rows = ColourMapRows((64, 128, 3), np.zeros((3, 256), np.float32), 16, 2, (tiles, box))
    with pytest.raises(ValueError, match="cut tiles"):
        rows(np.zeros((64, 128, 3), np.uint8), 8, 32)
    with pytest.raises(ValueError, match="shape"):
        rows(np.zeros((64, 120, 3), np.uint8), 0, 64)
    with pytest.raises(ValueError, match="out arrays"):
        ColourMapRows((64, 128, 3), None, 16, 2, (tiles, np.zeros((30, 64, 3), np.float32)))


@pytest.mark.parametrize("source_shape, size", [
    ((75, 203, 3), (101, 37)),    # down, odd sizes
    ((75, 203, 3), (406, 150)),   # up
    ((74, 202, 3), (101, 37)),    # halved exactly
    ((41, 97, 1), (60, 25)),      # one channel
    ((36, 64, 3), (64, 36)),      # the same size: copied
])
def test_row_resizer_matches_resize_linear_and_opencv(source_shape, size):
    rng = np.random.default_rng(size[0])
    frame = rng.integers(0, 256, (source_shape[0], source_shape[1] + 10, source_shape[2]),
                         dtype=np.uint8)
    # A column-sliced region, as the detector's: strided rows, contiguous pixels.
    region = frame[:, 3:3 + source_shape[1]]
    expected = resize_linear(region, size)
    np.testing.assert_array_equal(expected.reshape(expected.shape[0], -1), cv2.resize(
        np.ascontiguousarray(region), size, interpolation=cv2.INTER_LINEAR).reshape(
            expected.shape[0], -1))
    out = np.zeros(expected.shape, np.uint8)
    resizer = RowResizer(region.shape, size, out)
    for first, stop in bands(size[1], 7):
        out[...] = 0
        resizer(region, first, stop)
        np.testing.assert_array_equal(out[first:stop], expected[first:stop])
        assert not out[:first].any() and not out[stop:].any()


def test_row_resizer_checks_its_image_and_array():
    out = np.zeros((20, 30, 3), np.uint8)
    resizer = RowResizer((40, 60, 3), (30, 20), out)
    with pytest.raises(ValueError, match="shape"):
        resizer(np.zeros((40, 61, 3), np.uint8), 0, 20)
    with pytest.raises(ValueError, match="uint8"):
        resizer(np.zeros((40, 60, 3), np.float32), 0, 20)
    with pytest.raises(ValueError, match="out must be"):
        RowResizer((40, 60, 3), (30, 21), out)


@pytest.mark.parametrize("source_shape, size", [
    ((75, 203, 3), (101, 37)),    # linear
    ((74, 202, 3), (101, 37)),    # halved exactly
    ((36, 64, 3), (64, 36)),      # the same size: copied
])
@pytest.mark.parametrize("column_sliced", [True, False])
def test_a_bound_resize_reads_its_image_as_it_is_at_each_call(source_shape, size,
                                                             column_sliced):
    """``bind`` is made once and called frame after frame on an image refilled in
    place: each call must give what a fresh call on the image as it is gives."""
    rng = np.random.default_rng(size[1])
    frame = np.zeros((source_shape[0], source_shape[1] + 10, source_shape[2]), np.uint8)
    region = frame[:, 3:3 + source_shape[1]] if column_sliced else frame[:, :source_shape[1]]
    out = np.zeros((size[1], size[0], source_shape[2]), np.uint8)
    resizer = RowResizer(region.shape, size, out)
    function, arguments = resizer.bind(region, 4, size[1] - 3)
    for _ in range(3):
        frame[...] = rng.integers(0, 256, frame.shape, dtype=np.uint8)
        out[...] = 0
        function(*arguments)
        expected = resize_linear(region, size)
        np.testing.assert_array_equal(out[4:size[1] - 3], expected[4:size[1] - 3])
        assert not out[:4].any() and not out[size[1] - 3:].any()
    assert resizer.bind(region, 5, 5) is None


def test_a_bound_resize_of_an_image_with_gaps_in_its_rows_copies_it_at_each_call():
    # Every second column: the rows are not contiguous, so the kernel needs a
    # copy; one made when binding would go stale as the image is refilled.
    frame = np.zeros((75, 2 * 203, 3), np.uint8)
    region = frame[:, ::2]
    out = np.zeros((37, 101, 3), np.uint8)
    resizer = RowResizer(region.shape, (101, 37), out)
    function, arguments = resizer.bind(region, 0, 37)
    rng = np.random.default_rng(2)
    for _ in range(2):
        frame[...] = rng.integers(0, 256, frame.shape, dtype=np.uint8)
        function(*arguments)
        np.testing.assert_array_equal(out, resize_linear(np.ascontiguousarray(region),
                                                         (101, 37)))
