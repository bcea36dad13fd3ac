"""The phase layout of cell histograms and the HOG scorer that reads it.

``cell_histograms(..., phase_step=s)`` must hold exactly the values of the
standard ``(Hc, Wc, C, nbins)`` layout at the documented positions, and
``add_hog_scores_from_phase_cells`` must score every window as block
normalisation followed by a per-window dot product does.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from fastdet.kernels import score as score_module
from fastdet.kernels.blocks import NORM_CODES, normalize_blocks
from fastdet.kernels.hog import cell_histograms, phase_layout_shape, to_phase_layout
from fastdet.kernels.score import (add_hog_scores, add_hog_scores_from_cells,
                                   add_hog_scores_from_phase_cells, phase_scoring_pad,
                                   window_count)

from naive import naive_normalize_blocks


def random_image(rng, shape, kind):
    if kind == "uint8":
        return rng.integers(0, 256, shape, dtype=np.uint8)
    return rng.random(shape, dtype=np.float32)


def expected_phase(cells, step, pad):
    """The phase layout built position by position from its definition."""
    rows, cells_x, channels, nbins = cells.shape
    per_phase = -(-cells_x // step)
    out = np.zeros((rows, channels, nbins, step * per_phase + pad), np.float32)
    for cx in range(cells_x):
        out[:, :, :, (cx % step) * per_phase + cx // step] = cells[:, cx]
    return out


@pytest.mark.parametrize("kind", ["uint8", "float32"])
@pytest.mark.parametrize("shape, ppc, nbins", [
    ((64, 64, 3), (8, 8), 9),
    ((67, 131, 3), (8, 8), 9),
    ((45, 77, 1), (6, 5), 7),
    ((9, 200, 3), (8, 8), 12),
])
@pytest.mark.parametrize("step", [1, 2, 3, 4, 8])
def test_phase_cells_hold_the_standard_cells(kind, shape, ppc, nbins, step):
    image = random_image(np.random.default_rng(step), shape, kind)
    standard = cell_histograms(image, ppc, nbins)
    phase = cell_histograms(image, ppc, nbins, phase_step=step, phase_pad=2)
    assert phase.shape == phase_layout_shape(*standard.shape, step, 2)
    np.testing.assert_array_equal(phase, expected_phase(standard, step, 2))
    np.testing.assert_array_equal(to_phase_layout(standard, step, 2), phase)


def test_phase_cells_of_merged_channels_hold_the_standard_cells():
    image = random_image(np.random.default_rng(0), (40, 56, 3), "uint8")
    standard = cell_histograms(image, (8, 8), 9, merge_channels=True)
    phase = cell_histograms(image, (8, 8), 9, merge_channels=True, phase_step=3, phase_pad=1)
    np.testing.assert_array_equal(phase, expected_phase(standard, 3, 1))


@pytest.mark.parametrize("shape", [(33, 70, 3), (17, 20, 1), (8, 9, 3), (24, 200, 3)])
@pytest.mark.parametrize("step, pad", [(1, 0), (2, 2), (3, 1), (4, 2), (8, 3)])
def test_phase_cells_overwrite_a_dirty_buffer(shape, step, pad):
    # Positions no cell maps to (ends of short phases, padding; every phase
    # past the cells when they are fewer than the step) come out zero.
    image = random_image(np.random.default_rng(1), shape, "uint8")
    standard = cell_histograms(image, (8, 8), 9)
    dirty = np.full(phase_layout_shape(*standard.shape, step, pad), np.nan, np.float32)
    cell_histograms(image, (8, 8), 9, phase_step=step, phase_pad=pad, out=dirty)
    np.testing.assert_array_equal(dirty, expected_phase(standard, step, pad))


@pytest.mark.parametrize("shape", [(7, 7, 3), (8, 3, 3), (3, 40, 3), (16, 8, 1)])
def test_phase_cells_of_tiny_images(shape):
    image = random_image(np.random.default_rng(2), shape, "uint8")
    standard = cell_histograms(image, (8, 8), 9)
    phase = cell_histograms(image, (8, 8), 9, phase_step=2, phase_pad=2)
    np.testing.assert_array_equal(phase, expected_phase(standard, 2, 2))


def test_phase_cells_reject_a_wrong_buffer_and_step():
    image = np.zeros((32, 32, 3), np.uint8)
    with pytest.raises(ValueError, match="out must be"):
        cell_histograms(image, (8, 8), 9, phase_step=2, out=np.zeros((4, 4, 3, 9), np.float32))
    with pytest.raises(ValueError, match="phase_step"):
        cell_histograms(image, (8, 8), 9, phase_step=0)


def naive_scores(cells, cpb, norm, weights, step):
    """Per window: normalised blocks (naive numpy) dotted with the weights in float64."""
    blocks = naive_normalize_blocks(cells.astype(np.float64), cpb, norm)
    n = weights.shape[0]
    ny = window_count(blocks.shape[0], n, step)
    nx = window_count(blocks.shape[1], n, step)
    scores = np.zeros((ny, nx))
    for iy in range(ny):
        for ix in range(nx):
            window = blocks[iy * step:iy * step + n, ix * step:ix * step + n]
            scores[iy, ix] = np.sum(window * weights)
    return scores


@pytest.mark.parametrize("norm", sorted(NORM_CODES))
@pytest.mark.parametrize("cells_shape, cpb, n, step", [
    ((16, 40, 3, 9), (2, 2), 7, 2),
    ((19, 53, 3, 9), (2, 2), 7, 4),
    ((8, 160, 3, 9), (2, 2), 7, 8),
    ((11, 23, 1, 6), (3, 3), 4, 1),
    ((9, 31, 2, 5), (1, 2), 3, 3),
    ((12, 12, 3, 9), (2, 2), 11, 1),
    ((10, 121, 3, 9), (2, 2), 7, 1),
    ((9, 70, 1, 7), (1, 1), 5, 2),
])
def test_phase_scores_match_naive_blocks_and_windows(norm, cells_shape, cpb, n, step):
    rng = np.random.default_rng(sum(cells_shape) + step)
    cells = rng.random(cells_shape, dtype=np.float32)
    cells[rng.random(cells_shape[:3]) < 0.1] = 0.0  # some empty cells
    features = cells_shape[2] * cpb[0] * cpb[1] * cells_shape[3]
    weights = rng.normal(size=(n, n, features)).astype(np.float32)
    expected = naive_scores(cells, cpb, norm, weights, step)
    out = np.full(expected.shape, 0.5, np.float32)
    phase = to_phase_layout(cells, step, phase_scoring_pad(cells_shape[1], step, cpb))
    add_hog_scores_from_phase_cells(phase, cells_shape[1], cpb, norm, weights, step, out)
    np.testing.assert_allclose(out, expected + 0.5, rtol=1e-5, atol=2e-5)
    # Only the padding is scratch: the cells themselves are left as they were.
    real = step * -(-cells_shape[1] // step)
    np.testing.assert_array_equal(phase[..., :real], to_phase_layout(cells, step)[..., :real])


@pytest.mark.parametrize("norm", sorted(NORM_CODES))
def test_scores_from_cells_equal_blocks_then_windows(norm):
    rng = np.random.default_rng(3)
    image = rng.integers(0, 256, (101, 163, 3), dtype=np.uint8)
    cells = cell_histograms(image, (8, 8), 9)
    weights = rng.normal(size=(7, 7, 108)).astype(np.float32)
    blocks = normalize_blocks(cells, (2, 2), norm)
    grid = (window_count(blocks.shape[0], 7, 2), window_count(blocks.shape[1], 7, 2))
    expected = np.zeros(grid, np.float32)
    add_hog_scores(blocks, weights, 2, expected)
    fused = np.zeros(grid, np.float32)
    add_hog_scores_from_cells(cells, (2, 2), norm, weights, 2, fused)
    np.testing.assert_allclose(fused, expected, rtol=1e-5, atol=2e-5)


def test_phase_scores_of_a_real_frame_match_blocks_then_windows(data_dir):
    frame = cv2.imread(str(data_dir / "test_images" / "test1.jpg"))
    region = np.ascontiguousarray(frame[380:560])
    cells = cell_histograms(region, (8, 8), 9)
    weights = np.random.default_rng(4).normal(size=(7, 7, 108)).astype(np.float32)
    blocks = normalize_blocks(cells, (2, 2), "L2-Hys")
    for step in (2, 4, 8):
        grid = (window_count(blocks.shape[0], 7, step), window_count(blocks.shape[1], 7, step))
        expected = np.zeros(grid, np.float32)
        add_hog_scores(blocks, weights, step, expected)
        out = np.zeros(grid, np.float32)
        phase = cell_histograms(region, (8, 8), 9, phase_step=step,
                                phase_pad=phase_scoring_pad(cells.shape[1], step, (2, 2)))
        add_hog_scores_from_phase_cells(phase, cells.shape[1], (2, 2), "L2-Hys", weights, step,
                                        out)
        np.testing.assert_allclose(out, expected, rtol=1e-5, atol=2e-5)


def test_phase_scores_of_all_zero_cells_are_zero():
    phase = np.zeros(phase_layout_shape(10, 20, 3, 9, 2, phase_scoring_pad(20, 2, (2, 2))),
                     np.float32)
    out = np.zeros((2, 7), np.float32)
    weights = np.ones((7, 7, 108), np.float32)
    add_hog_scores_from_phase_cells(phase, 20, (2, 2), "L2-Hys", weights, 2, out)
    np.testing.assert_array_equal(out, 0.0)


def test_phase_scores_with_no_windows_leave_out_alone():
    phase = np.zeros(phase_layout_shape(4, 4, 3, 9, 2, phase_scoring_pad(4, 2, (2, 2))),
                     np.float32)
    out = np.zeros((0, 0), np.float32)
    add_hog_scores_from_phase_cells(phase, 4, (2, 2), "L2", np.ones((7, 7, 108), np.float32),
                                    2, out)
    assert out.shape == (0, 0)


def test_phase_scores_reject_mismatched_inputs():
    phase = np.zeros(phase_layout_shape(16, 20, 3, 9, 2, phase_scoring_pad(20, 2, (2, 2))),
                     np.float32)
    with pytest.raises(ValueError, match="features per block"):
        add_hog_scores_from_phase_cells(phase, 20, (2, 2), "L2", np.ones((7, 7, 100), np.float32),
                                        2, np.zeros((1, 1), np.float32))
    with pytest.raises(ValueError, match="positions"):
        add_hog_scores_from_phase_cells(np.ascontiguousarray(phase[..., :-2]), 20, (2, 2), "L2",
                                        np.ones((7, 7, 108), np.float32), 2,
                                        np.zeros((1, 1), np.float32))
    with pytest.raises(ValueError, match="C-contiguous float32"):
        add_hog_scores_from_phase_cells(phase.astype(np.float64), 20, (2, 2), "L2",
                                        np.ones((7, 7, 108), np.float32), 2,
                                        np.zeros((1, 1), np.float32))
    with pytest.raises(ValueError, match="do not fit"):
        add_hog_scores_from_phase_cells(phase, 20, (2, 2), "L2", np.ones((7, 7, 108), np.float32),
                                        2, np.zeros((9, 1), np.float32))


@pytest.mark.parametrize("norm", ["L2-Hys", "L1"])
@pytest.mark.parametrize("step", [1, 2, 4])
def test_parallel_phase_scores_equal_serial(norm, step):
    rng = np.random.default_rng(step)
    cells = rng.random((41, 57, 3, 9), dtype=np.float32)
    weights = rng.normal(size=(7, 7, 108)).astype(np.float32)
    phase = to_phase_layout(cells, step, phase_scoring_pad(57, step, (2, 2)))
    grid = (window_count(40, 7, step), window_count(56, 7, step))
    serial = np.zeros(grid, np.float32)
    parallel = np.zeros(grid, np.float32)
    add_hog_scores_from_phase_cells(phase, 57, (2, 2), norm, weights, step, serial)
    add_hog_scores_from_phase_cells(phase, 57, (2, 2), norm, weights, step, parallel,
                                    parallel=True)
    np.testing.assert_array_equal(parallel, serial)
    np.testing.assert_allclose(serial, naive_scores(cells, (2, 2), norm, weights, step),
                               rtol=1e-5, atol=2e-5)


def test_l2_hys_as_none_scores_as_its_code(monkeypatch):
    """L2-Hys reaches the kernel as None (only its normaliser compiled); as its
    code the kernel chooses among the four at run time: the same scores, bit
    for bit, and another code gives other scores."""
    rng = np.random.default_rng(3)
    cells = rng.random((23, 41, 3, 9), dtype=np.float32)
    weights = rng.normal(size=(7, 7, 108)).astype(np.float32)
    phase = to_phase_layout(cells, 2, phase_scoring_pad(41, 2, (2, 2)))
    grid = (window_count(22, 7, 2), window_count(40, 7, 2))
    scores = {}
    for name, code in (("none", None), ("code", NORM_CODES["L2-Hys"]), ("l2", NORM_CODES["L2"])):
        monkeypatch.setattr(score_module, "_norm_argument", lambda norm, code=code: code)
        scores[name] = np.zeros(grid, np.float32)
        add_hog_scores_from_phase_cells(phase.copy(), 41, (2, 2), "L2-Hys", weights, 2,
                                        scores[name])
    np.testing.assert_array_equal(scores["none"], scores["code"])
    assert not np.array_equal(scores["none"], scores["l2"])
    np.testing.assert_allclose(scores["none"], naive_scores(cells, (2, 2), "L2-Hys", weights, 2),
                               rtol=1e-5, atol=2e-5)
