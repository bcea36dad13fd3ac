"""Linear-SVM scores of every sliding window of one scale, without per-window extraction.

A window's decision value is ``bias + w_hog . hog + w_spatial . spatial +
w_hist . hist``.  Each part is added into an ``(Ny, Nx)`` score grid by its
own kernel, reading maps computed once per scale:

* HOG: from a ready block map, the window's ``n x n`` blocks are ``n``
  contiguous runs (one per block row) dotted with the matching rows of the
  weights (:func:`add_hog_scores`); from cells in the phase layout of the
  window step, each block row is normalised once along the whole row and
  added into the windows that contain it
  (:func:`add_hog_scores_from_phase_cells`, what the detector uses);
* spatial: likewise, ``S`` contiguous pixel rows of the box-averaged image;
* histogram: the part is linear in the per-pixel bin indicators, so it equals
  the window sum of a per-pixel weight ``sum_c lut[c, value_c]``; windows are
  made of whole tiles, so an integral image over per-tile sums gives it in
  four reads per window.

The detector adds all three parts of a band of window rows in one kernel
call (:func:`score_window_rows`), which takes the GIL back once instead of
three times.

Window ``(iy, ix)`` has its top-left pixel at ``(iy * step_px, ix * step_px)``
of the scale's image (``step_px`` = cells per step x pixels per cell).

Where the phase-layout scorer's time goes (one thread, Xeon with AVX-512):
on the published five scales of a 1280x720 frame (1.4 M normalised block
values, 861 windows) about 0.75 ms, down from 2.3 ms with loops Numba
vectorised; 0.8-0.95 ms on the default search's 1020 windows.
Two blocks of LLVM vector IR do the work, 16 block positions or windows per
vector: :func:`_normalise_blocks` (about 0.4 ms) and :func:`_window_dots`
(about 0.3 ms).  Both are bound by moving the normalised block row (up to
100 KB) through L2, not by arithmetic, hence the dots' sharing of each loaded
vector among all the window rows that contain its block row.
"""

import numba
import numpy as np
from llvmlite import ir
from numba import njit, prange, types, uint64
from numba.extending import intrinsic

from ._llvm import (HAVE_AVX2, HAVE_AVX512F, counted_loop, fused_multiply_add, load_vector,
                    splat, store_vector)
from .alloc import empty, full, zeros
from .blocks import EPS, NORM_CODES
from .hog import to_phase_layout
from .inner import CALLED_FROM_KERNELS_ONLY
from .views import flat as flat_view

#: Lanes of the row dot products' vector accumulators, and how many of those
#: take turns per window (latency: one running sum would wait on its own adds).
_DOT_LANES = 16
_DOT_CHAINS = 4
#: Windows of a row dotted at once, sharing each weight vector loaded: four
#: with AVX-512; three where a 16-lane vector is two registers (AVX2's 16
#: hold four windows' accumulators only by spilling them: on an AMD Zen 5 the
#: AVX2 build's spatial rows took 0.88x the time with three, 42 against 48
#: us for a 4 x 77 grid).  Any count gives the same bits.
_DOT_WINDOWS = 4 if HAVE_AVX512F else 3


def _row_window_dots(windows, fixed_length=None):
    """An intrinsic ``dots(image_flat, row_len, y0, x0, x_step, weights_flat,
    rows, length, out_row, ox, count)`` adding, for each window ``i < count``
    (``1 <= count <= windows``),
    ``sum over r, k of image[y0 + r, x0 + i * x_step + k] * weights[r, k]``
    (flat arrays, ``row_len`` elements an image row) to ``out_row[ox + i]``.
    With fewer than ``windows``, the missing ones repeat the last window's
    reads and are not stored: one compiled block serves the rest of a row.

    The order of each window's sums is fixed in the IR, not left to LLVM:
    lane ``l`` of accumulator ``j`` adds the products of the elements
    ``k = 64 q + 16 j + l`` of every row in turn (the rest of a row's whole
    vectors go to accumulator 0, its last ``length % 16`` elements to a scalar
    sum), then the accumulators and their lanes are added in a fixed tree.
    Products and sums are separate instructions, never fused.  So a window's
    sum is the same bit for bit on every CPU and for any ``windows``: LLVM's
    own vectorisation of a reassociating loop chose its partial sums by the
    target's vector width (16 lanes on an AMD Zen 4 with AVX-512, 8 with AVX2
    or on Intel's AVX-512 cores, which prefer 256-bit vectors) and fused the
    products into the sums only where the CPU has FMA.  The loads, not the
    arithmetic, bound the loop: windows dotted together share each weight
    vector (the spatial scores of a 1280x720 frame took 0.59-0.70x the time
    of LLVM's loop four windows at a time, 0.72x one at a time; AMD EPYC
    Zen 4 with AVX-512, alternating in one process).

    ``fixed_length``: a block for rows of that many elements only (``length``
    must equal it), each row's products written out in full, in the same
    order, instead of three loops whose trip counts are computed per row.
    """
    f32 = ir.FloatType()
    vector = ir.VectorType(f32, _DOT_LANES)

    def codegen(context, builder, signature, args):
        i64 = ir.IntType(64)
        image, weights, out = [context.make_array(signature.args[k])(context, builder,
                                                                     args[k]).data
                               for k in (0, 5, 8)]
        row_len, top, left, x_step, n_rows, n, ox, count = [
            context.cast(builder, args[k], signature.args[k], types.int64)
            for k in (1, 2, 3, 4, 6, 7, 9, 10)]
        lanes = ir.Constant(i64, _DOT_LANES)
        per_turn = ir.Constant(i64, _DOT_LANES * _DOT_CHAINS)
        vectors = builder.udiv(n, lanes)
        turns = builder.udiv(vectors, ir.Constant(i64, _DOT_CHAINS))
        done = builder.mul(turns, per_turn)
        whole = builder.mul(vectors, lanes)
        zero = ir.Constant(vector, [0.0] * _DOT_LANES)
        last = builder.sub(count, ir.Constant(i64, 1))
        lefts = [builder.add(left, builder.mul(x_step, builder.select(
            builder.icmp_signed("<", ir.Constant(i64, i), count), ir.Constant(i64, i), last)))
                 for i in range(windows)]

        def add_products(bases, w_base, offset, totals, vtype=vector):
            """``totals[i] + image[bases[i] + offset] * weights[w_base + offset]``."""
            if vtype is f32:
                load = lambda data, index: builder.load(builder.gep(data, [index]))  # noqa: E731
            else:
                load = lambda data, index: load_vector(builder, data, index, vtype)  # noqa: E731
            weight = load(weights, builder.add(w_base, offset))
            return [builder.fadd(total, builder.fmul(load(image, builder.add(base, offset)),
                                                     weight))
                    for base, total in zip(bases, totals)]

        def fixed_row(bases, w_base, values):
            """The row's products in the loops' order, with constant offsets."""
            per = _DOT_CHAINS + 1
            out = list(values)
            whole_vectors = fixed_length // _DOT_LANES
            full_turns = whole_vectors // _DOT_CHAINS
            for v in range(whole_vectors):
                chain = v % _DOT_CHAINS if v < full_turns * _DOT_CHAINS else 0
                slots = [i * per + chain for i in range(windows)]
                added = add_products(bases, w_base, ir.Constant(i64, v * _DOT_LANES),
                                     [out[k] for k in slots])
                for k, value in zip(slots, added):
                    out[k] = value
            for k in range(whole_vectors * _DOT_LANES, fixed_length):
                slots = [i * per + _DOT_CHAINS for i in range(windows)]
                added = add_products(bases, w_base, ir.Constant(i64, k),
                                     [out[j] for j in slots], f32)
                for j, value in zip(slots, added):
                    out[j] = value
            return out

        def row(r, values):
            # values: per window, _DOT_CHAINS vector sums and a scalar one.
            per = _DOT_CHAINS + 1
            start = builder.mul(builder.add(top, r), row_len)
            bases = [builder.add(start, x) for x in lefts]
            w_base = builder.mul(r, n)
            if fixed_length is not None:
                return fixed_row(bases, w_base, values)
            sums = [list(values[i * per:i * per + _DOT_CHAINS]) for i in range(windows)]
            tails = [values[i * per + _DOT_CHAINS] for i in range(windows)]

            def turn(q, flat):
                offset = builder.mul(q, per_turn)
                out = [None] * len(flat)
                for j in range(_DOT_CHAINS):
                    added = add_products(bases, w_base,
                                         builder.add(offset, ir.Constant(i64, j * _DOT_LANES)),
                                         flat[j::_DOT_CHAINS])
                    out[j::_DOT_CHAINS] = added
                return out

            flat = counted_loop(builder, turns, [v for chain in sums for v in chain], turn)

            def single(v, firsts):
                return add_products(bases, w_base, builder.add(done, builder.mul(v, lanes)),
                                    firsts)

            firsts = counted_loop(builder, builder.sub(vectors, builder.udiv(done, lanes)),
                                  flat[::_DOT_CHAINS], single)
            flat[::_DOT_CHAINS] = firsts
            tails = counted_loop(builder, builder.sub(n, whole), tails, lambda k, t: (
                add_products(bases, w_base, builder.add(whole, k), t, f32)))
            following = []
            for i in range(windows):
                following += flat[i * _DOT_CHAINS:(i + 1) * _DOT_CHAINS] + [tails[i]]
            return following

        per = _DOT_CHAINS + 1
        values = counted_loop(builder, n_rows,
                              ([zero] * _DOT_CHAINS + [ir.Constant(f32, 0.0)]) * windows, row)
        for i in range(windows):
            sums = values[i * per:i * per + _DOT_CHAINS]
            while len(sums) > 1:
                sums = [builder.fadd(a, b) for a, b in zip(sums[::2], sums[1::2])]
            total = sums[0]
            width = _DOT_LANES
            while width > 1:
                width //= 2
                total = builder.fadd(*[builder.shuffle_vector(total, total, ir.Constant(
                    ir.VectorType(ir.IntType(32), width), list(range(begin, begin + width))))
                    for begin in (0, width)])
            total = builder.fadd(builder.extract_element(total, ir.Constant(ir.IntType(32), 0)),
                                 values[i * per + _DOT_CHAINS])
            with builder.if_then(builder.icmp_signed("<", ir.Constant(i64, i), count)):
                slot = builder.gep(out, [builder.add(ox, ir.Constant(i64, i))])
                builder.store(builder.fadd(builder.load(slot), total), slot)
        return context.get_dummy_value()

    def dots(typingctx, image_flat, row_len, y0, x0, x_step, weights_flat, rows, length,
             out_row, ox, count):
        return (types.void(image_flat, row_len, y0, x0, x_step, weights_flat, rows, length,
                           out_row, ox, count), codegen)

    dots.__name__ = dots.__qualname__ = (
        f"_row_window_dots_{windows}" + ("" if fixed_length is None else f"_n{fixed_length}"))
    return intrinsic(dots)


_row_dots = _row_window_dots(_DOT_WINDOWS)
#: Elements of a row of the default spatial features (32 x 32 pixels, 3 channels).
SPATIAL_ROW = 96
#: Their block, each row written out in full (the same sums, bit for bit): the
#: general block's three loops a row, their trip counts computed per call and
#: unrolled by LLVM with remainders, took about 37 cycles a window row where
#: the row's 24 vector loads take 12.  The spatial part of a frame's scores
#: took 0.63x the time (0.161-0.255 against 0.259-0.408 ms, 3 alternating
#: pairs; AMD EPYC Zen 3, AVX2), its scoring 0.86x; the score family compiles
#: about 0.3 s longer (medians of 3, 3.65 against 3.31 s).
_row_dots_spatial = _row_window_dots(_DOT_WINDOWS, SPATIAL_ROW)


@njit(cache=True, nogil=True, inline="always")
def _add_grid_row(image_flat, row_len, y0, step_cols, weights_flat, rows, length, out_row):
    """One row of windows of :func:`_add_grid`, _DOT_WINDOWS at a time."""
    cols = out_row.shape[0]
    if length == SPATIAL_ROW:
        for ix in range(0, cols, _DOT_WINDOWS):
            _row_dots_spatial(image_flat, row_len, y0, ix * step_cols, step_cols, weights_flat,
                              rows, length, out_row, ix, min(_DOT_WINDOWS, cols - ix))
    else:
        for ix in range(0, cols, _DOT_WINDOWS):
            _row_dots(image_flat, row_len, y0, ix * step_cols, step_cols, weights_flat, rows,
                      length, out_row, ix, min(_DOT_WINDOWS, cols - ix))


@njit(cache=True, nogil=True, inline="always")
def _add_grid(image2d, weights2d, step_rows, step_cols, out):
    rows, length = weights2d.shape
    image_flat = flat_view(image2d)
    weights_flat = flat_view(weights2d)
    for iy in range(out.shape[0]):
        _add_grid_row(image_flat, image2d.shape[1], iy * step_rows, step_cols, weights_flat,
                      rows, length, out[iy])


@njit(cache=True, parallel=True)
def _add_grid_parallel(image2d, weights2d, step_rows, step_cols, out):
    rows, length = weights2d.shape
    image_flat = flat_view(image2d)
    weights_flat = flat_view(weights2d)
    for iy in prange(out.shape[0]):
        _add_grid_row(image_flat, image2d.shape[1], iy * step_rows, step_cols, weights_flat,
                      rows, length, out[iy])


def add_hog_scores(blocks, weights, step_cells, out, parallel=False):
    """Add the HOG part of every window's score to ``out``.

    Parameters
    ----------
    blocks : ndarray of float32, shape (Hb, Wb, F)
        Block map of the scale (C-contiguous).
    weights : ndarray of float32, shape (n, n, F)
        HOG weights of one window, in block-map order.
    step_cells : int
        Window step in cells (= blocks).
    out : ndarray of float32, shape (Ny, Nx)
        Score grid, added to in place; every window must fit in ``blocks``.
    parallel : bool
        Spread window rows over Numba's threads.
    """
    n, _, length = weights.shape
    _check_fits(out, blocks.shape[:2], (n, n), step_cells)
    image2d = blocks.reshape(blocks.shape[0], blocks.shape[1] * length)
    weights2d = weights.reshape(n, n * length)
    kernel = _add_grid_parallel if parallel else _add_grid
    kernel(image2d, weights2d, step_cells, step_cells * length, out)


def add_hog_scores_from_cells(cells, cells_per_block, norm, weights, step_cells, out, eps=EPS):
    """Normalise blocks and add every window's HOG score in one pass.

    Equivalent to :func:`fastdet.kernels.blocks.normalize_blocks` followed by
    :func:`add_hog_scores`, without writing the block map: the cells are
    copied into the phase layout and scored by
    :func:`add_hog_scores_from_phase_cells` (the detector computes that
    layout directly).

    Parameters
    ----------
    cells : ndarray of float32, shape (Hc, Wc, C, nbins)
    cells_per_block : tuple of int
    norm : str
        Block norm, as in :func:`~fastdet.kernels.blocks.normalize_blocks`.
    weights : ndarray of float32, shape (n, n, F)
    step_cells : int
    out : ndarray of float32, shape (Ny, Nx)
    eps : float
    """
    pad = phase_scoring_pad(cells.shape[1], step_cells, cells_per_block)
    phase = to_phase_layout(cells, step_cells, pad)
    add_hog_scores_from_phase_cells(phase, cells.shape[1], cells_per_block, norm, weights,
                                    step_cells, out, eps)


# -- HOG scores from phase-layout cells ---------------------------------------
#: Windows scored per call of the dot-product block: one 512-bit vector.
_LANES = 16


def _window_dots(rows, chunks=1):
    """An intrinsic ``dots(weights, w_base, w_step, blocks, stride, offset, second,
    channels, per_channel, acc, a0, a_step)`` adding the dot products of one
    block row with the weights of ``rows`` window rows, ``chunks`` times
    _LANES windows each.

    Feature ``f`` of the block row is ``blocks[f * stride + offset + lane]``
    for the first _LANES windows, ``offset + _LANES + lane`` for the next, and
    so on.  Window row ``i < rows`` weighs it by ``weights[w_base + i * w_step
    + f]`` and adds its sum to ``acc[a0 + i * a_step + lane]`` (the next
    _LANES windows: ``+ _LANES``; steps may be negative).  Features come in
    ``channels`` groups of ``per_channel``, each group's sum multiplied by
    ``second[c * stride + offset + lane]`` (L2-Hys's second normalisation;
    ones for the other norms).

    The windows are the vector lanes, so there are no horizontal sums, and
    every block vector loaded serves all the window rows containing the block
    row: the loads, not the FMAs, bound this loop.  Numba's loop vectoriser
    would only vectorise along windows with a scalar tail (rows of 12 to 52
    windows run mostly in it), and its SLP vectoriser is off.  Each window's
    sums are the same for any ``chunks``: more chunks only put more
    independent chains of multiply-adds side by side, for block rows that
    only one or two window rows contain (two chains each would otherwise
    wait on their own adds).
    """

    def codegen(context, builder, signature, args):
        i64, f32 = ir.IntType(64), ir.FloatType()
        vector = ir.VectorType(f32, _LANES)
        data = {k: context.make_array(signature.args[k])(context, builder, args[k]).data
                for k in (0, 3, 6, 9)}
        weights, blocks, second, acc = data[0], data[3], data[6], data[9]
        w_base, w_step, stride, offset, channels, per_channel, a0, a_step = [
            context.cast(builder, args[k], signature.args[k], types.int64)
            for k in (1, 2, 4, 5, 7, 8, 10, 11)]
        zero = ir.Constant(vector, [0.0] * _LANES)
        w_bases = [builder.add(w_base, builder.mul(w_step, ir.Constant(i64, i)))
                   for i in range(rows)]
        shifts = [ir.Constant(i64, chunk * _LANES) for chunk in range(chunks)]
        per_chain = rows * chunks

        def add_feature(feature, sums):
            # sums[chunk * rows + i]: window row i of that chunk.
            at = builder.add(builder.mul(feature, stride), offset)
            xs = [load_vector(builder, blocks, builder.add(at, shift), vector)
                  for shift in shifts]
            out = list(sums)
            for i, w_row in enumerate(w_bases):
                weight = builder.load(builder.gep(weights, [builder.add(w_row, feature)]))
                weight = splat(builder, weight, vector)
                for chunk, x in enumerate(xs):
                    slot = chunk * rows + i
                    out[slot] = fused_multiply_add(builder, weight, x, sums[slot])
            return out

        def channel(c, totals):
            first = builder.mul(c, per_channel)
            two = ir.Constant(i64, 2)

            # Two chains per window row keep enough FMAs in flight for one
            # row; the same two for every ``rows`` and ``chunks``, so a
            # window's sum does not depend on how its row was grouped.
            def pair(g, sums):
                even = builder.add(first, builder.mul(g, two))
                return (add_feature(even, sums[:per_chain])
                        + add_feature(builder.add(even, ir.Constant(i64, 1)), sums[per_chain:]))

            sums = counted_loop(builder, builder.sdiv(per_channel, two),
                                [zero] * (2 * per_chain), pair)
            sums = [builder.fadd(a, b) for a, b in zip(sums[:per_chain], sums[per_chain:])]
            last = builder.add(first, builder.sub(per_channel, ir.Constant(i64, 1)))
            sums = counted_loop(builder, builder.srem(per_channel, two), sums,
                                lambda k, partial: add_feature(last, partial))
            at = builder.add(builder.mul(c, stride), offset)
            scales = [load_vector(builder, second, builder.add(at, shift), vector)
                      for shift in shifts]
            return [fused_multiply_add(builder, part, scales[slot // rows], total)
                    for slot, (part, total) in enumerate(zip(sums, totals))]

        totals = counted_loop(builder, channels, [zero] * per_chain, channel)
        for slot, total in enumerate(totals):
            chunk, i = divmod(slot, rows)
            index = builder.add(builder.add(a0, builder.mul(a_step, ir.Constant(i64, i))),
                                shifts[chunk])
            store_vector(builder, builder.fadd(load_vector(builder, acc, index, vector), total),
                         acc, index)
        return context.get_dummy_value()

    def dots(typingctx, weights, w_base, w_step, blocks, stride, offset, second, channels,
             per_channel, acc, a0, a_step):
        return (types.void(weights, w_base, w_step, blocks, stride, offset, second, channels,
                           per_channel, acc, a0, a_step), codegen)

    dots.__name__ = dots.__qualname__ = f"_window_dots_{rows}x{chunks}"
    return intrinsic(dots)


#: Window rows scored together per block row, at most: as many as keep the
#: block's sums in registers (two chains of 16 lanes per row; any grouping
#: gives the same bits).  AVX-512's 32 registers hold four rows' sums, AVX2's
#: 16 three: with four, three sums went through the stack at every feature
#: pair, and the blocks took 1.22x the time of three (AMD EPYC Zen 3, the
#: same window rows).  Without AVX2 (16 lanes are four SSE registers, and
#: without FMA its exact emulation needs more), one row: 0.78x the time of
#: four under ``NUMBA_CPU_NAME=generic``.
_MAX_ROWS = 4 if HAVE_AVX512F else 3 if HAVE_AVX2 else 1
_window_dots_1 = _window_dots(1)
_window_dots_2 = _window_dots(2)
_window_dots_3 = _window_dots(3)
_window_dots_4 = _window_dots(4)
#: Chunks of _LANES windows dotted side by side where a block row has few
#: window rows: as many as keep ``rows * chunks`` at _MAX_ROWS or below (the
#: same registers as the widest grouping).
_PAIRED_ROWS = _MAX_ROWS // 2
_window_dots_1x2 = _window_dots(1, 2)
_window_dots_2x2 = _window_dots(2, 2)


def _normalise_blocks(norm_code, copies=1):
    """An intrinsic ``normalise(cells, c_base, row_stride, bin_stride, k, cpb_y, cpb_x,
    nbins, energy, e_base, e_row_stride, p0, bias, hys_bias, normalised, n_base,
    stride, second, s_base)`` normalising one channel of ``copies * _LANES``
    blocks of a block row.

    The block at position ``p0 + lane`` has cell ``(dy, dx)`` bin ``b`` at
    ``cells[c_base + dy * row_stride + b * bin_stride + dx * k + p0 + lane]``
    and that cell's energy (sum of squares or of absolute values over bins)
    at ``energy[e_base + dy * e_row_stride + dx * k + p0 + lane]``.  Feature
    ``f = (dy * cpb_x + dx) * nbins + b`` of the block goes to
    ``normalised[n_base + f * stride + p0 + lane]``.  ``bias`` is added to the
    norm's sum: eps for L1 norms, eps**2 for L2 norms.  For L2-Hys
    (``norm_code`` 3) the clipped values' second inverse norm,
    ``1 / sqrt(sum of squares + hys_bias)``, goes to ``second[s_base + p0 +
    lane]``.  Sums run in the order of a plain loop over (dy, dx) and then
    features, so the values equal a scalar loop's.

    ``copies``: vectors of _LANES positions done side by side, each with its
    own sums in the same order, so the values are the same for any ``copies``.
    L2-Hys's sum of the clipped squares is one chain of dependent
    multiply-adds per vector (36 for the default block); one vector at a time
    it waits on that chain.
    """

    def codegen(context, builder, signature, args):
        f32 = ir.FloatType()
        vector = ir.VectorType(f32, _LANES)
        arrays = {k: context.make_array(signature.args[k])(context, builder, args[k]).data
                  for k in (0, 8, 14, 17)}
        cells, energy, normalised, second = arrays[0], arrays[8], arrays[14], arrays[17]
        (c_base, row_stride, bin_stride, k, cpb_y, cpb_x, nbins, e_base, e_row_stride, p0,
         n_base, stride, s_base) = [context.cast(builder, args[j], signature.args[j], types.uint64)
                                    for j in (1, 2, 3, 4, 5, 6, 7, 9, 10, 11, 15, 16, 18)]

        bias, hys_bias = splat(builder, args[12], vector), splat(builder, args[13], vector)
        sqrt = builder.module.declare_intrinsic(
            f"llvm.sqrt.v{_LANES}f32", fnty=ir.FunctionType(vector, [vector]))
        zero = ir.Constant(vector, [0.0] * _LANES)
        one = ir.Constant(vector, [1.0] * _LANES)
        clip = ir.Constant(vector, [float(np.float32(0.2))] * _LANES)
        shifts = [ir.Constant(p0.type, copy * _LANES) for copy in range(copies)]

        def energy_row(dy, sums):
            row = builder.add(builder.add(e_base, builder.mul(dy, e_row_stride)), p0)

            def cell(dx, sums):
                start = builder.add(row, builder.mul(dx, k))
                return [builder.fadd(total, load_vector(builder, energy,
                                                        builder.add(start, shift), vector))
                        for total, shift in zip(sums, shifts)]

            return counted_loop(builder, cpb_x, sums, cell)

        inverses = []
        for total in counted_loop(builder, cpb_y, [zero] * copies, energy_row):
            norm = builder.fadd(total, bias)
            if norm_code >= 2:
                norm = builder.call(sqrt, [norm])
            inverses.append(builder.fdiv(one, norm))

        def cell_row(dy, sums):
            row = builder.add(builder.add(c_base, builder.mul(dy, row_stride)), p0)

            def cell(dx, sums):
                start = builder.add(row, builder.mul(dx, k))
                first = builder.mul(builder.add(builder.mul(dy, cpb_x), dx), nbins)

                def feature(b, sums):
                    at = builder.add(start, builder.mul(b, bin_stride))
                    f = builder.add(first, b)
                    out_at = builder.add(n_base, builder.add(builder.mul(f, stride), p0))
                    following = []
                    for total, inv, shift in zip(sums, inverses, shifts):
                        value = builder.fmul(load_vector(builder, cells, builder.add(at, shift),
                                                         vector), inv)
                        if norm_code == 1:
                            value = builder.call(sqrt, [value])
                        elif norm_code == 3:
                            value = builder.select(builder.fcmp_ordered("<", value, clip), value,
                                                   clip)
                        store_vector(builder, value, normalised, builder.add(out_at, shift))
                        following.append(fused_multiply_add(builder, value, value, total)
                                         if norm_code == 3 else total)
                    return following

                return counted_loop(builder, nbins, sums, feature)

            return counted_loop(builder, cpb_x, sums, cell)

        sums_sq = counted_loop(builder, cpb_y, [zero] * copies, cell_row)
        if norm_code == 3:
            for sum_sq, shift in zip(sums_sq, shifts):
                second_inv = builder.fdiv(one, builder.call(sqrt, [builder.fadd(sum_sq,
                                                                                hys_bias)]))
                store_vector(builder, second_inv, second,
                             builder.add(builder.add(s_base, p0), shift))
        return context.get_dummy_value()

    def normalise(typingctx, cells, c_base, row_stride, bin_stride, k, cpb_y, cpb_x, nbins,
                  energy, e_base, e_row_stride, p0, bias, hys_bias, normalised, n_base, stride,
                  second, s_base):
        return (types.void(cells, c_base, row_stride, bin_stride, k, cpb_y, cpb_x, nbins, energy,
                           e_base, e_row_stride, p0, bias, hys_bias, normalised, n_base, stride,
                           second, s_base), codegen)

    normalise.__name__ = normalise.__qualname__ = (
        f"_normalise_blocks_{norm_code}" + (f"x{copies}" if copies > 1 else ""))
    return intrinsic(normalise)


#: Vectors of block positions L2-Hys normalises side by side (see _normalise_blocks).
_HYS_COPIES = 2


_normalise_l1 = _normalise_blocks(0)
_normalise_l1_sqrt = _normalise_blocks(1)
_normalise_l2 = _normalise_blocks(2)
_normalise_l2_hys = _normalise_blocks(3)
_normalise_l2_hys_side_by_side = _normalise_blocks(3, _HYS_COPIES)


# No fastmath: contracted into FMAs where the CPU has them, the energies would
# round differently on CPUs without (the loops vectorise along positions anyway).
@njit(cache=True, **CALLED_FROM_KERNELS_ONLY)
def _phase_energy(cells_flat, base, nbins, length, absolute, energy, e_base):
    """energy[e_base + i] = sum over bins of |v| (``absolute``: L1 norms) or v**2 (L2 norms)."""
    for i in range(uint64(length)):
        energy[e_base + i] = 0.0
    for b in range(uint64(nbins)):
        row = base + b * uint64(length)
        if absolute:
            for i in range(uint64(length)):
                energy[e_base + i] += abs(cells_flat[row + i])
        else:
            for i in range(uint64(length)):
                v = cells_flat[row + i]
                energy[e_base + i] += v * v


@njit(cache=True, nogil=True, inline="always")
def _fill_wrapped_phases(cells, per_phase, step, wrap):
    """Write the ``wrap`` phases after the ``step`` real ones (see
    :func:`phase_scoring_pad`): position ``q * K + j`` gets cell column
    ``q + j * step``, i.e. that of phase ``q % step`` at ``j + q // step``
    (zero past the grid)."""
    rows, channels, nbins, length = cells.shape
    flat = flat_view(cells)
    k = uint64(per_phase)
    for row in range(uint64(rows * channels * nbins)):
        base = row * uint64(length)
        for q in range(uint64(step), uint64(step + wrap)):
            shift = q // uint64(step)
            src = base + (q % uint64(step)) * k + shift
            dest = base + q * k
            keep = k - min(shift, k)
            for j in range(keep):
                flat[dest + j] = flat[src + j]
            for j in range(keep, k):
                flat[dest + j] = 0.0


@njit(cache=True, nogil=True)
def _score_window_rows(wrapped, cells, per_phase, cpb_y, cpb_x, norm_code, eps, weights, step,
                       out, first_row, stop_row, band_scores, spatial, spatial_weights,
                       spatial_step_rows, spatial_step_cols, tiles, tiles_per_window, tiles_step):
    """Add the scores of window rows ``first_row`` .. ``stop_row - 1`` (a band) to ``out``.

    HOG part (empty ``weights`` switch it off): the cell rows ``wrapped``
    (those the band reads) get their wrapped phases filled
    (:func:`_fill_wrapped_phases`); then cell ``bx + dx`` of the block at
    position ``p`` sits at ``p + dx * K`` for every block, so each block row
    is normalised in whole-row loops of a multiple of _LANES positions, and
    each row of windows is scored _LANES windows at a time.  Spatial part
    (empty ``spatial_weights`` switch it off) and histogram part
    (``tiles_per_window`` 0 switches it off): added to ``band_scores``, the
    band's rows of ``out``, from the band's rows of their maps.

    ``norm_code`` is the block norm's code (``NORM_CODES``), or None for
    L2-Hys (:func:`_norm_argument`).  Numba drops the branches of a None
    argument before typing, so calls with None compile only the L2-Hys
    normaliser, not all four (about 0.35 s of the family's first compile); a
    code is chosen at run time among the four.

    One kernel for the three parts: each call from Python takes the GIL
    back when it returns (see :func:`score_window_rows`).  The HOG part's
    code is here rather than in a function of its own that this one calls:
    Numba optimises a called kernel's code again inside its caller, and for
    this one that cost about 1 s of compiling.
    """
    if weights.shape[0] and first_row < stop_row:
        _fill_wrapped_phases(wrapped, per_phase, step, cpb_x - 1)
        rows, channels, nbins, length = cells.shape
        n = weights.shape[0]
        n_features = weights.shape[2]
        rows_out, cols_out = out.shape
        k = uint64(per_phase)
        lanes = uint64(_LANES)
        # Block positions, rounded up to whole vectors: padding blocks are scored
        # into lanes nobody reads.
        stride = (uint64(step) * k + lanes - uint64(1)) // lanes * lanes
        chunks = (cols_out + _LANES - 1) // _LANES
        row_len = chunks * _LANES
        cells_flat = flat_view(cells)
        weights_flat = flat_view(weights)
        first_block = first_row * step
        stop_block = (stop_row - 1) * step + n
        # Per cell of the band's block rows: the sum a block norm is built from.
        # A None norm_code is L2-Hys, the only norm then compiled (see the
        # docstring): every test of it starts with ``norm_code is None``.
        if norm_code is None:
            absolute = False
        else:
            absolute = norm_code <= 1
        energy = empty(rows * channels * length, dtype=np.float32)
        for cy in range(first_block, stop_block + cpb_y - 1):
            for c in range(channels):
                base = uint64((cy * channels + c) * nbins * length)
                _phase_energy(cells_flat, base, nbins, length, absolute, energy,
                              uint64((cy * channels + c) * length))
        per_channel = uint64(cpb_y * cpb_x * nbins)
        # Whole vectors past the last feature: the window dots read that far.
        normalised = zeros(uint64(n_features) * stride + lanes, dtype=np.float32)
        second = full(uint64(channels) * stride + lanes, 1.0, np.float32)
        eps32 = np.float32(eps)
        eps_sq = np.float32(eps * eps)
        bias = eps32 if absolute else eps_sq
        row_stride = uint64(channels * nbins * length)
        e_row_stride = uint64(channels * length)
        scores = zeros((stop_row - first_row) * row_len, dtype=np.float32)
        for by in range(first_block, stop_block):
            for c in range(channels):
                c_base = uint64((by * channels + c) * nbins * length)
                e_base = uint64((by * channels + c) * length)
                n_base = uint64(c) * per_channel * stride
                s_base = uint64(c) * stride
                p0 = uint64(0)
                if norm_code is None or norm_code == 3:
                    side_by_side = uint64(_HYS_COPIES) * lanes
                    while p0 + side_by_side <= stride:
                        _normalise_l2_hys_side_by_side(
                            cells_flat, c_base, row_stride, uint64(length), k, uint64(cpb_y),
                            uint64(cpb_x), uint64(nbins), energy, e_base, e_row_stride, p0,
                            bias, eps_sq, normalised, n_base, stride, second, s_base)
                        p0 += side_by_side
                for p0 in range(p0, stride, lanes):
                    if norm_code is None or norm_code == 3:
                        _normalise_l2_hys(cells_flat, c_base, row_stride, uint64(length), k,
                                          uint64(cpb_y), uint64(cpb_x), uint64(nbins), energy,
                                          e_base, e_row_stride, p0, bias, eps_sq, normalised,
                                          n_base, stride, second, s_base)
                    elif norm_code == 2:
                        _normalise_l2(cells_flat, c_base, row_stride, uint64(length), k,
                                      uint64(cpb_y), uint64(cpb_x), uint64(nbins), energy, e_base,
                                      e_row_stride, p0, bias, eps_sq, normalised, n_base, stride,
                                      second, s_base)
                    elif norm_code == 1:
                        _normalise_l1_sqrt(cells_flat, c_base, row_stride, uint64(length), k,
                                           uint64(cpb_y), uint64(cpb_x), uint64(nbins), energy,
                                           e_base, e_row_stride, p0, bias, eps_sq, normalised,
                                           n_base, stride, second, s_base)
                    else:
                        _normalise_l1(cells_flat, c_base, row_stride, uint64(length), k,
                                      uint64(cpb_y), uint64(cpb_x), uint64(nbins), energy, e_base,
                                      e_row_stride, p0, bias, eps_sq, normalised, n_base, stride,
                                      second, s_base)
            # Window rows iy whose n block rows include ``by``, scored together
            # in groups of up to _MAX_ROWS.
            first = max(first_row, (by - n + step) // step)
            last = min(stop_row - 1, by // step)
            for s in range(n):
                offset = (s % step) * per_phase + s // step
                for group in range(first, last + 1, _MAX_ROWS):
                    count = min(_MAX_ROWS, last + 1 - group)
                    w_base = ((by - group * step) * n + s) * n_features
                    w_step = -step * n * n_features
                    chunk = 0
                    if count <= _PAIRED_ROWS:
                        while chunk + 2 <= chunks:
                            a0 = (group - first_row) * row_len + chunk * _LANES
                            at = offset + chunk * _LANES
                            if count == 2:
                                _window_dots_2x2(weights_flat, w_base, w_step, normalised,
                                                 stride, at, second, channels, per_channel,
                                                 scores, a0, row_len)
                            else:
                                _window_dots_1x2(weights_flat, w_base, w_step, normalised,
                                                 stride, at, second, channels, per_channel,
                                                 scores, a0, row_len)
                            chunk += 2
                    for chunk in range(chunk, chunks):
                        a0 = (group - first_row) * row_len + chunk * _LANES
                        at = offset + chunk * _LANES
                        if count == 4:
                            _window_dots_4(weights_flat, w_base, w_step, normalised, stride, at,
                                           second, channels, per_channel, scores, a0, row_len)
                        elif count == 3:
                            _window_dots_3(weights_flat, w_base, w_step, normalised, stride, at,
                                           second, channels, per_channel, scores, a0, row_len)
                        elif count == 2:
                            _window_dots_2(weights_flat, w_base, w_step, normalised, stride, at,
                                           second, channels, per_channel, scores, a0, row_len)
                        else:
                            _window_dots_1(weights_flat, w_base, w_step, normalised, stride, at,
                                           second, channels, per_channel, scores, a0, row_len)
        # Unsigned indices: with Python's negative-index wraparound LLVM turned
        # this contiguous copy into vector gathers (slow on AMD).
        for iy in range(first_row, stop_row):
            base = uint64((iy - first_row) * row_len)
            row = out[iy]
            for ix in range(uint64(cols_out)):
                row[ix] += scores[base + ix]
    if spatial_weights.shape[0]:
        _add_grid(spatial, spatial_weights, spatial_step_rows, spatial_step_cols, band_scores)
    if tiles_per_window:
        _add_tile_window_sums(tiles, tiles_per_window, tiles_step, band_scores)


@njit(cache=True, parallel=True)
def _add_hog_scores_phase_parallel(cells, per_phase, cpb_y, cpb_x, norm_code, eps, weights, step,
                                   out, bands, no_cells, no_map, no_weights):
    # Bands of window rows write disjoint score rows; block rows on a band
    # edge are normalised by both bands.  The caller fills the wrapped phases
    # (no_cells: none to fill here).
    rows_out = out.shape[0]
    for band in prange(bands):
        _score_window_rows(no_cells, cells, per_phase, cpb_y, cpb_x, norm_code, eps, weights,
                           step, out, band * rows_out // bands, (band + 1) * rows_out // bands,
                           out, no_map, no_weights, 1, 1, no_map, 0, 1)


def _norm_argument(norm):
    """``norm_code`` of :func:`_score_window_rows` for a block norm name: None for
    L2-Hys (the default options' norm, compiled alone), else its code."""
    return None if norm == "L2-Hys" else NORM_CODES[norm]


# The arguments of _score_window_rows that switch a part off (empty arrays: nothing is
# ever written to them).  The norm is None, as the detector's calls have it, so
# that a scale without HOG features needs no other compiled version.
_NO_HOG = (np.zeros((0, 0, 0, 0), np.float32), np.zeros((0, 0, 0, 0), np.float32), 1, 1, 1,
           None, float(EPS), np.zeros((0, 0, 0), np.float32), 1)
_NO_SPATIAL = (np.zeros((0, 0), np.float32), np.zeros((0, 0), np.float32), 1, 1)
_NO_TILES = (np.zeros((0, 0), np.float32), 0, 1)


def phase_scoring_pad(cells_x, step_cells, cells_per_block):
    """Positions :func:`add_hog_scores_from_phase_cells` needs after the phases.

    The scorer writes ``cells_per_block[1] - 1`` *wrapped* phases there
    (phase ``step + q`` holds cell column ``q + (j + 1) * step`` at index
    ``j``), so that every block's cells sit at fixed offsets from the block,
    and reads up to a vector past them.

    Returns
    -------
    int
        The ``pad`` of :func:`fastdet.kernels.hog.phase_layout_shape`.
    """
    per_phase = -(-int(cells_x) // int(step_cells))
    return (int(cells_per_block[1]) - 1) * per_phase + _LANES


def add_hog_scores_from_phase_cells(cells, cells_x, cells_per_block, norm, weights, step_cells,
                                    out, eps=EPS, parallel=False, window_rows=None):
    """Normalise blocks and add every window's HOG score, one block row at a time.

    Equivalent to :func:`fastdet.kernels.blocks.normalize_blocks` followed by
    :func:`add_hog_scores`, but the block map is never written to memory,
    every block row is normalised in whole-row vector loops and the windows
    of a row are scored 16 at a time.  The cells come in the phase layout of
    :func:`fastdet.kernels.hog.phase_layout_shape` for ``step_cells``, with
    at least :func:`phase_scoring_pad` positions of padding: the blocks a row
    of windows reads at any offset are then contiguous.

    Parameters
    ----------
    cells : ndarray of float32, shape (Hc, C, nbins, L)
        Phase-layout cells.  The padding positions after the phases are
        scratch: this function overwrites them.
    cells_x : int
        Cell columns ``Wc`` of the grid.
    cells_per_block : tuple of int
    norm : str
        Block norm, as in :func:`~fastdet.kernels.blocks.normalize_blocks`.
    weights : ndarray of float32, shape (n, n, F)
        HOG weights of one window, blocks ordered (channel, cell_y, cell_x, bin).
    step_cells : int
    out : ndarray of float32, shape (Ny, Nx)
        Score grid, added to in place.
    eps : float
    parallel : bool
        Spread bands of window rows over Numba's threads.
    window_rows : tuple of int, optional
        ``(first, stop)``: score only these window rows; only the cell rows
        they cover are read (and their padding written).
    """
    cpb_y, cpb_x = int(cells_per_block[0]), int(cells_per_block[1])
    n = weights.shape[0]
    per_phase = _phase_cells_checked(cells, cells_x, cells_per_block, weights, step_cells, out)
    first, stop = (0, out.shape[0]) if window_rows is None else (
        max(0, int(window_rows[0])), min(out.shape[0], int(window_rows[1])))
    if out.shape[1] == 0 or first >= stop:
        return
    # The cell rows the band's windows cover.
    wrapped = cells[first * step_cells:(stop - 1) * step_cells + n + cpb_y - 1]
    weights = np.ascontiguousarray(weights, dtype=np.float32)
    args = (cells, per_phase, cpb_y, cpb_x, _norm_argument(norm), float(eps), weights,
            int(step_cells), out)
    bands = min(numba.get_num_threads(), stop - first) if parallel and window_rows is None else 1
    if bands > 1:
        _fill_wrapped_phases(wrapped, per_phase, int(step_cells), cpb_x - 1)
        _add_hog_scores_phase_parallel(*args, bands, _NO_HOG[0], *_NO_SPATIAL[:2])
    else:
        _score_window_rows(wrapped, *args, first, stop, out, *_NO_SPATIAL, *_NO_TILES)


def score_window_rows(scores, window_rows, window, step_px, hog=None, spatial=None, tiles=None):
    """Add every part of the scores of some window rows, in one kernel call.

    The same sums as :func:`add_hog_scores_from_phase_cells`,
    :func:`add_spatial_scores` and :func:`add_tile_window_sums` called in
    turn on the rows' windows.  Each call from Python takes the GIL back when
    it returns, and a thread that finds it held sleeps: on the 2-core
    virtual machines here a sleeping thread takes 30-50 microseconds to
    wake, so frames scored on two threads at once lose less time with one
    call a scale than with three.

    Parameters
    ----------
    scores : ndarray of float32, shape (Ny, Nx)
        The scale's score grid (C-contiguous), added to in place.
    window_rows : tuple of int
        ``(first, stop)``: window rows ``first`` .. ``stop - 1`` are scored.
    window : int
        Window side in pixels of the scale.
    step_px : int
        Window step in pixels of the scale.
    hog : tuple, optional
        ``(cells, cells_x, cells_per_block, norm, weights, step_cells)``, as
        :func:`add_hog_scores_from_phase_cells` takes them: the scale's
        phase-layout cells (their padding positions are scratch), and so on.
    spatial : tuple, optional
        ``(box, weights)``: the scale's box-averaged image, shape
        ``(Hs, Ws, 3)`` with ``window // S`` pixels per box, and the spatial
        weights, shape ``(S, S, 3)``.
    tiles : tuple, optional
        ``(tile_sums, tile)``: the scale's per-tile histogram weight sums
        (:func:`fastdet.kernels.colour.colour_maps`) and the tile side in
        pixels.
    """
    WindowRowScorer(scores.shape, window, step_px, hog, spatial, tiles)(scores, *window_rows)


class WindowRowScorer:
    """:func:`score_window_rows` bound to one scale's maps and weights, checked once.

    The detector scores the same scales frame after frame, from the same
    arrays: checked and sized here once, a call runs little Python beside
    the kernel.  That Python holds the GIL, which a thread scoring another
    frame then waits for (and, asleep, takes 35-50 us to wake on the 2-core
    virtual machines here); so do the bound resize, cell and colour-map
    calls (:class:`~fastdet.kernels.resize.RowResizer`,
    :class:`~fastdet.kernels.hog.PhaseCellRows`,
    :class:`~fastdet.kernels.colour.ColourMapRows`).

    Parameters
    ----------
    grid : tuple of int
        ``(Ny, Nx)``: the shape of the score grids the calls add to.
    window, step_px, hog, spatial, tiles
        As :func:`score_window_rows` takes them; the arrays are kept, and
        each call reads them as they are then.
    """

    def __init__(self, grid, window, step_px, hog=None, spatial=None, tiles=None):
        grid = (int(grid[0]), int(grid[1]))
        self.grid = grid
        self.window, self.step_px = int(window), int(step_px)
        shape_only = np.empty(grid, np.float32)
        self._hog = None
        if hog is not None:
            cells, cells_x, cells_per_block, norm, weights, step_cells = hog
            per_phase = _phase_cells_checked(cells, cells_x, cells_per_block, weights,
                                             step_cells, shape_only)
            cpb_y, cpb_x = int(cells_per_block[0]), int(cells_per_block[1])
            step_cells = int(step_cells)
            # Cell rows a band reads: from its first window's to its last
            # window's last block's last cell.
            self._hog = (cells, step_cells, weights.shape[0] + cpb_y - 1,
                         (cells, per_phase, cpb_y, cpb_x, _norm_argument(norm), float(EPS),
                          np.ascontiguousarray(weights, dtype=np.float32), step_cells))
        self._spatial = None
        if spatial is not None:
            box, weights = spatial
            size, _, channels = weights.shape
            factor = self.window // size
            _check_fits(shape_only, box.shape[:2], (size, size), self.step_px // factor)
            if not box.flags.c_contiguous or box.dtype != np.float32:
                raise ValueError("the spatial box image must be a C-contiguous float32 array")
            self._spatial = (box, factor, box.shape[1] * channels,
                             np.ascontiguousarray(weights.reshape(size, size * channels),
                                                  dtype=np.float32),
                             self.step_px // factor, self.step_px // factor * channels)
        self._tiles = None
        if tiles is not None:
            tile_sums, tile = tiles
            tile = int(tile)
            _check_fits(shape_only, tile_sums.shape, (self.window // tile, self.window // tile),
                        self.step_px // tile)
            if not tile_sums.flags.c_contiguous or tile_sums.dtype != np.float32:
                raise ValueError("the tile sums must be a C-contiguous float32 array")
            self._tiles = (tile_sums, tile, self.window // tile, self.step_px // tile)

    def __call__(self, scores, first, stop):
        """Add the scores of window rows ``first`` .. ``stop - 1`` to ``scores``."""
        arguments = self.arguments(scores, first, stop)
        if arguments is not None:
            _score_window_rows(*arguments)

    def arguments(self, scores, first, stop):
        """The arguments of the ``_score_window_rows`` kernel call :meth:`__call__`
        makes, or None when it scores nothing."""
        if scores.shape != self.grid:
            raise ValueError(f"the score grid has shape {scores.shape}, "
                             f"the scorer was made for {self.grid}")
        if scores.dtype != np.float32 or not scores.flags.c_contiguous:
            raise ValueError("the score grid must be a C-contiguous float32 array")
        first, stop = max(0, int(first)), min(self.grid[0], int(stop))
        if self.grid[1] == 0 or first >= stop:
            return None
        band_scores = scores[first:stop]
        # Pixel rows the band's windows cover.
        top, bottom = first * self.step_px, (stop - 1) * self.step_px + self.window
        hog_args = _NO_HOG
        if self._hog is not None:
            cells, step_cells, extent, bound = self._hog
            hog_args = (cells[first * step_cells:(stop - 1) * step_cells + extent],) + bound
        spatial_args = _NO_SPATIAL
        if self._spatial is not None:
            box, factor, row_length, weights2d, step_rows, step_cols = self._spatial
            band = box[top // factor:bottom // factor]
            spatial_args = (band.reshape(band.shape[0], row_length), weights2d, step_rows,
                            step_cols)
        tile_args = _NO_TILES
        if self._tiles is not None:
            tile_sums, tile, size, step = self._tiles
            tile_args = (tile_sums[top // tile:bottom // tile], size, step)
        return (*hog_args, scores, first, stop, band_scores, *spatial_args, *tile_args)


def add_spatial_scores(spatial, weights, step_px, out, parallel=False):
    """Add the spatial-colour part of every window's score to ``out``.

    Parameters
    ----------
    spatial : ndarray of float32, shape (Hs, Ws, 3)
        Box-averaged colour image of the scale (C-contiguous).
    weights : ndarray of float32, shape (S, S, 3)
    step_px : int
        Window step in pixels of ``spatial``.
    out : ndarray of float32, shape (Ny, Nx)
    parallel : bool
    """
    size, _, channels = weights.shape
    _check_fits(out, spatial.shape[:2], (size, size), step_px)
    image2d = spatial.reshape(spatial.shape[0], spatial.shape[1] * channels)
    weights2d = weights.reshape(size, size * channels)
    kernel = _add_grid_parallel if parallel else _add_grid
    kernel(image2d, weights2d, step_px, step_px * channels, out)


@njit(cache=True, nogil=True, inline="always")
def _add_tile_window_sums(tiles, size, step, out):
    """out[iy, ix] += sum of tiles[iy*step : +size, ix*step : +size]."""
    rows, cols = tiles.shape
    integral = zeros((rows + 1, cols + 1), dtype=np.float64)
    for y in range(rows):
        running = 0.0
        for x in range(cols):
            running += tiles[y, x]
            integral[y + 1, x + 1] = integral[y, x + 1] + running
    for iy in range(out.shape[0]):
        y0 = iy * step
        for ix in range(out.shape[1]):
            x0 = ix * step
            out[iy, ix] += (integral[y0 + size, x0 + size] - integral[y0, x0 + size]
                            - integral[y0 + size, x0] + integral[y0, x0])


def add_tile_window_sums(tiles, tiles_per_window, step_tiles, out):
    """Add each window's sum of per-tile values to ``out``.

    Used for the colour-histogram part of the score: ``tiles`` are the
    per-tile weight sums of :func:`fastdet.kernels.colour.colour_maps`.

    Parameters
    ----------
    tiles : ndarray of float32, shape (Ty, Tx)
    tiles_per_window : int
        Window side in tiles.
    step_tiles : int
        Window step in tiles.
    out : ndarray of float32, shape (Ny, Nx)
    """
    _check_fits(out, tiles.shape, (tiles_per_window, tiles_per_window), step_tiles)
    _add_tile_window_sums(tiles, tiles_per_window, step_tiles, out)


def _phase_cells_checked(cells, cells_x, cells_per_block, weights, step_cells, out):
    """Check phase-layout cells, HOG weights and a score grid against each other.

    Returns
    -------
    int
        Positions per phase.
    """
    cpb_y, cpb_x = int(cells_per_block[0]), int(cells_per_block[1])
    n, _, length = weights.shape
    rows, channels, nbins, positions = cells.shape
    if cells.dtype != np.float32 or not cells.flags.c_contiguous:
        raise ValueError("phase-layout cells must be a C-contiguous float32 array")
    if length != channels * cpb_y * cpb_x * nbins:
        raise ValueError(f"weights have {length} features per block, cells give "
                         f"{channels * cpb_y * cpb_x * nbins}")
    per_phase = -(-int(cells_x) // step_cells)
    needed = step_cells * per_phase + phase_scoring_pad(cells_x, step_cells, cells_per_block)
    if positions < needed:
        raise ValueError(f"phase-layout cells need {needed} positions (see phase_scoring_pad) "
                         f"for {cells_x} columns stepped by {step_cells}, got {positions}")
    _check_fits(out, (rows - cpb_y + 1, cells_x - cpb_x + 1), (n, n), step_cells)
    return per_phase


def _check_fits(out, map_shape, window_shape, step):
    for axis in range(2):
        if out.shape[axis] and (out.shape[axis] - 1) * step + window_shape[axis] > map_shape[axis]:
            raise ValueError(f"{out.shape[axis]} windows of {window_shape[axis]} stepped by {step} "
                             f"do not fit in a map of {map_shape[axis]} along axis {axis}")


def window_count(map_length, window_length, step):
    """Number of windows of ``window_length`` stepped by ``step`` along an axis."""
    if map_length < window_length:
        return 0
    return (map_length - window_length) // step + 1
