"""The single-thread uint8 fast path of ``cell_histograms`` (nbins 9, 8x8
cells, 1 or 3 channels: vector accumulators, threshold bin rule) against the
general lookup-table path and a naive numpy reference."""

from __future__ import annotations


import cv2
import numpy as np
import pytest

from fastdet.kernels import hog
from fastdet.kernels.hog import cell_histograms, orientation_lut, threshold_bins, to_phase_layout
from naive import naive_cell_histograms

PHASE = dict(phase_step=4, phase_pad=2)


def table_path(image, **kwargs):
    """cell_histograms with the fast path switched off (the lookup-table path)."""
    saved = hog._FAST_CHANNELS
    hog._FAST_CHANNELS = ()
    try:
        return cell_histograms(image, (8, 8), 9, **kwargs)
    finally:
        hog._FAST_CHANNELS = saved


def fast_path(image, **kwargs):
    calls = []
    original = hog._cell_rows_u8_fast

    def spy(*args):
        calls.append(args)
        return original(*args)

    hog._cell_rows_u8_fast = spy
    try:
        result = cell_histograms(image, (8, 8), 9, **kwargs)
    finally:
        hog._cell_rows_u8_fast = original
    cells = (image.shape[0] // 8) * (image.shape[1] // 8)
    assert calls or cells == 0, "the fast path was not taken"
    return result


def assert_close(fast, table):
    assert fast.shape == table.shape
    scale = max(1.0, float(np.abs(table).max(initial=0.0)))
    np.testing.assert_allclose(fast, table, rtol=0, atol=2e-6 * scale)


def gradients():
    g = np.arange(-255, 256)
    gy, gx = np.meshgrid(g, g, indexing="ij")
    return gx, gy


def test_threshold_rule_equals_the_table_for_every_integer_gradient():
    gx, gy = gradients()
    rule = threshold_bins(gx, gy, 9).ravel()
    lut = orientation_lut(9).astype(np.int64)
    nonzero = ((gx != 0) | (gy != 0)).ravel()
    assert nonzero.sum() == 511 * 511 - 1
    np.testing.assert_array_equal(rule[nonzero], lut[nonzero])
    assert hog._fast_rule_ok(9)


def test_a_wrong_threshold_is_caught():
    """The check that guards the fast path can fail."""
    gx, gy = gradients()
    good = hog._fast_thresholds(9)
    bad = list(good)
    bad[1] = float(np.float32(bad[1]) * np.float32(0.999))
    saved = hog._fast_thresholds
    hog._fast_thresholds = lambda nbins: bad
    try:
        rule = threshold_bins(gx, gy, 9).ravel()
        accepted = hog._fast_rule_ok.__wrapped__(9)
    finally:
        hog._fast_thresholds = saved
    nonzero = ((gx != 0) | (gy != 0)).ravel()
    assert not np.array_equal(rule[nonzero], orientation_lut(9)[nonzero])
    assert not accepted


SHAPES = [(8, 8), (8, 16), (9, 15), (16, 16), (17, 33), (24, 48), (24, 56), (8, 40),
          (40, 47), (64, 64), (23, 100), (31, 129), (7, 64), (64, 7), (1, 1), (3, 200)]


@pytest.mark.parametrize("channels", [1, 3])
@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("layout", ["standard", "phase"])
def test_fast_path_matches_table_path_random(channels, shape, layout):
    rng = np.random.default_rng(hash((channels, shape, layout)) % 2**32)
    image = rng.integers(0, 256, shape + (channels,), dtype=np.uint8)
    kwargs = PHASE if layout == "phase" else {}
    assert_close(fast_path(image, **kwargs), table_path(image, **kwargs))


@pytest.mark.parametrize("channels", [1, 3])
@pytest.mark.parametrize("shape", [(17, 33), (24, 48), (40, 47), (64, 64)])
def test_fast_path_matches_naive(channels, shape):
    rng = np.random.default_rng(7)
    image = rng.integers(0, 256, shape + (channels,), dtype=np.uint8)
    expected = naive_cell_histograms(image, (8, 8), 9)
    assert_close(fast_path(image), expected.astype(np.float32))


@pytest.mark.parametrize("channels", [1, 3])
def test_fast_path_extreme_gradients(channels):
    """Checkerboards of 0 / 255 give gradients of +-255 on both axes."""
    yy, xx = np.mgrid[:40, :51]
    image = np.where((yy // 1 + xx // 2) % 2, 255, 0).astype(np.uint8)
    image = np.repeat(image[:, :, None], channels, axis=2)
    image[:, :, 0] = image[:, :, 0][::-1]
    for kwargs in ({}, PHASE):
        assert_close(fast_path(image, **kwargs), table_path(image, **kwargs))


@pytest.fixture(scope="module")
def frame_hls():
    image = cv2.imread("/work/shared/data/test_images/test1.jpg")
    if image is None:
        pytest.fail("cannot read /work/shared/data/test_images/test1.jpg", pytrace=False)
    return np.ascontiguousarray(cv2.cvtColor(image, cv2.COLOR_BGR2HLS))


@pytest.mark.parametrize("layout", ["standard", "phase"])
def test_fast_path_matches_table_path_on_a_real_frame(frame_hls, layout):
    kwargs = PHASE if layout == "phase" else {}
    scaled = np.ascontiguousarray(cv2.resize(frame_hls[360:540], (1697, 225)))
    for image in (frame_hls, scaled, np.ascontiguousarray(frame_hls[:, :, 1:2]),
                  np.ascontiguousarray(frame_hls[3:172, 5:605])):
        assert_close(fast_path(image, **kwargs), table_path(image, **kwargs))


def test_fast_path_matches_naive_on_a_real_crop(frame_hls):
    image = np.ascontiguousarray(frame_hls[400:465, 300:437])
    assert_close(fast_path(image), naive_cell_histograms(image, (8, 8), 9).astype(np.float32))


def test_fast_path_fills_a_dirty_out_buffer():
    rng = np.random.default_rng(3)
    image = rng.integers(0, 256, (33, 70, 3), dtype=np.uint8)
    out = np.full((4, 8, 3, 9), np.nan, np.float32)
    fast_path(image, out=out)
    assert_close(out, table_path(image))


def test_other_configurations_take_the_table_path():
    rng = np.random.default_rng(4)
    image = rng.integers(0, 256, (32, 32, 2), dtype=np.uint8)
    called = []
    original = hog._cell_rows_u8_fast
    hog._cell_rows_u8_fast = lambda *args: called.append(args)
    try:
        cell_histograms(image, (8, 8), 9)
        cell_histograms(image[:, :, :1].copy(), (8, 8), 8)
        cell_histograms(image[:, :, :1].copy(), (6, 8), 9)
    finally:
        hog._cell_rows_u8_fast = original
    assert not called


@pytest.mark.parametrize("layout", ["standard", "phase"])
def test_parallel_fast_path_equals_serial(layout):
    rng = np.random.default_rng(5)
    image = rng.integers(0, 256, (203, 331, 3), dtype=np.uint8)
    extra = {"phase_step": 4, "phase_pad": 2} if layout == "phase" else {}
    serial = cell_histograms(image, (8, 8), 9, **extra)
    parallel = cell_histograms(image, (8, 8), 9, parallel=True, **extra)
    np.testing.assert_array_equal(parallel, serial)
    if layout == "phase":
        assert_close(parallel, to_phase_layout(table_path(image), 4, 2))
    else:
        assert_close(parallel, table_path(image))


def test_the_orientation_table_is_kept_beside_the_kernels(tmp_path, monkeypatch):
    """Saved once, loaded afterwards; a damaged copy is rebuilt, never trusted."""
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    expected = orientation_lut(9)
    np.testing.assert_array_equal(hog._bin_lut.__wrapped__(9), expected)
    saved = hog._lut_path(9)
    assert saved.parent == tmp_path and saved.exists()
    np.testing.assert_array_equal(np.load(saved)["lut"], expected)
    saved.write_bytes(b"not a table")
    np.testing.assert_array_equal(hog._bin_lut.__wrapped__(9), expected)
    np.testing.assert_array_equal(np.load(saved)["lut"], expected)
    # A copy whose content changed but still parses is caught by its checksum.
    flipped = expected.copy()
    flipped[1000] ^= 1
    np.savez(saved, lut=flipped, sha256=np.load(saved)["sha256"])
    np.testing.assert_array_equal(hog._bin_lut.__wrapped__(9), expected)
    np.testing.assert_array_equal(np.load(saved)["lut"], expected)


def _block_kernel(channels, first, last, lanes, mask_then_add, two_pass):
    """A jitted call of one group block variant (no cache: test-only variants)."""
    from numba import njit

    block = hog._group_block(channels, 8, 8, 9, first, last, lanes=lanes,
                             mask_then_add=mask_then_add, two_pass=two_pass)

    @njit
    def run(flat, height, row_bytes, y0, x0, scratch):
        block(flat, height, row_bytes, y0, x0, scratch)

    return run


def _planned_sums(plan, lanes, channels, ppc_x=8, nbins=9):
    """What a plan stores where, symbolically: each sum a set of its two terms
    (IEEE addition is commutative, so a pair's order does not change a bit)."""
    pieces = hog._GROUP_CELLS * ppc_x * channels // lanes
    vectors = [[("x", b, e // (channels * ppc_x), e % channels, (e // channels) % ppc_x)
                for e in range(q * lanes, (q + 1) * lanes)]
               for b in range(nbins) for q in range(pieces)]
    for level in plan.levels:
        following = []
        for left, right in level:
            operands = []
            for (first_source, second_source), mask in (left, right):
                a = vectors[first_source]
                both = a + (a if second_source is None else vectors[second_source])
                operands.append([both[m] for m in mask])
            following.append([frozenset(pair) for pair in zip(*operands)])
        vectors = following
    return [term for vector in vectors for term in vector]


@pytest.mark.parametrize("channels", [1, 3])
@pytest.mark.parametrize("lanes", [4, 8, 16])
def test_every_reduction_plan_adds_the_same_pairs_in_the_same_tree(channels, lanes):
    """((x0 + x4) + (x2 + x6)) + ((x1 + x5) + (x3 + x7)) for every (bin, cell,
    channel), whatever the plan: so builds of any lane width give the same bits."""
    plan = hog._reduction_plan(lanes, channels, 8, 9)
    stored = _planned_sums(plan, lanes, channels)
    assert plan.size == len(stored)
    for b in range(9):
        for cell in range(hog._GROUP_CELLS):
            for c in range(channels):
                x = [("x", b, cell, c, p) for p in range(8)]
                tree = frozenset([frozenset([frozenset([x[0], x[4]]), frozenset([x[2], x[6]])]),
                                  frozenset([frozenset([x[1], x[5]]), frozenset([x[3], x[7]])])])
                assert stored[plan.index[(b * hog._GROUP_CELLS + cell) * channels + c]] == tree


def test_the_half_lane_plan_is_the_eight_lane_colour_plan():
    """Its shuffles are whole 128-bit halves or vshufps patterns (the greedy
    plan's arbitrary masks took two or three shuffles each with AVX2)."""
    plan = hog._reduction_plan(8, 3, 8, 9)
    assert len(plan.levels) == 3
    halves = ([0, 1, 2, 3, 8, 9, 10, 11], [4, 5, 6, 7, 12, 13, 14, 15])
    for left, right in plan.levels[0]:
        assert left[1] in halves and right[1] in halves
    for level in plan.levels[1:]:
        for shuffles in level:
            for _, mask in shuffles:
                # The same pattern in both halves, each lane from its own half.
                assert [m % 4 for m in mask[4:]] == [m % 4 for m in mask[:4]]
                assert all((m % 8) // 4 == lane // 4 for lane, m in enumerate(mask))


@pytest.mark.parametrize("channels", [1, 3])
@pytest.mark.parametrize("lanes, mask_then_add", [(4, True), (8, True), (16, False)])
def test_every_block_variant_gives_the_naive_cells_and_both_orders_agree(channels, lanes,
                                                                         mask_then_add):
    """The block in one pass (AVX-512 machines) and in two passes (the others),
    at each lane width, whatever this CPU runs natively.

    The image is 2 groups wide and 3 cell rows tall, so the blocks see the
    first and last image rows and columns (``first`` / ``last`` variants)."""
    rng = np.random.default_rng(channels * 100 + lanes)
    group = hog._GROUP_CELLS * 8
    image = rng.integers(0, 256, (24, 2 * group, channels), dtype=np.uint8)
    image[8:12] = np.where(rng.random((4, 2 * group, channels)) < 0.5, 0, 255)
    expected = naive_cell_histograms(image, (8, 8), 9).astype(np.float32)
    plan = hog._reduction_plan(lanes, channels, 8, 9)
    flat, row_bytes = image.ravel(), 2 * group * channels
    for first, last, x_group in ((True, False, 0), (False, True, 1)):
        got = {}
        for two_pass in (False, True):
            run = _block_kernel(channels, first, last, lanes, mask_then_add, two_pass)
            cells = np.empty((3, hog._GROUP_CELLS, channels, 9), np.float32)
            for cell_row in range(3):
                scratch = np.full(plan.size, np.nan, np.float32)
                run(flat, 24, row_bytes, cell_row * 8, x_group * group * channels, scratch)
                # scratch[index[(b * cells + cell) * channels + c]]: the mean of bin b.
                means = scratch[plan.index].reshape(9, hog._GROUP_CELLS, channels)
                cells[cell_row] = means.transpose(1, 2, 0)
            got[two_pass] = cells
            columns = slice(x_group * hog._GROUP_CELLS, (x_group + 1) * hog._GROUP_CELLS)
            assert_close(cells, expected[:, columns])
        np.testing.assert_array_equal(got[True], got[False])


@pytest.mark.parametrize("channels", [1, 3])
def test_blocks_of_every_lane_width_give_the_same_bits(channels):
    """The eight-lane colour block has a plan of its own (_half_lane_plan)."""
    rng = np.random.default_rng(channels)
    group = hog._GROUP_CELLS * 8
    image = rng.integers(0, 256, (17, 3 * group, channels), dtype=np.uint8)
    flat, row_bytes = image.ravel(), 3 * group * channels
    for first, last, x_group in ((True, False, 0), (False, False, 1), (False, True, 2)):
        means = []
        for lanes, mask_then_add in ((4, True), (8, True), (16, False)):
            plan = hog._reduction_plan(lanes, channels, 8, 9)
            scratch = np.full(plan.size, np.nan, np.float32)
            _block_kernel(channels, first, last, lanes, mask_then_add, True)(
                flat, 17, row_bytes, 8, x_group * group * channels, scratch)
            means.append(scratch[plan.index])
        assert not np.isnan(means[0]).any()
        for other in means[1:]:
            np.testing.assert_array_equal(other, means[0])
