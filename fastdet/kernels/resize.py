"""Bilinear resize of uint8 images, bit-identical to OpenCV's ``INTER_LINEAR``.

The detector resizes each search scale's region with
``cv2.resize(region, (w, h), interpolation=cv2.INTER_LINEAR)``.  This kernel
returns exactly the same bytes (the tests compare with OpenCV on many sizes)
in one single-threaded pass.  OpenCV's rule, as reproduced here:

* columns: ``fx = float32((dx + 0.5) * (1 / (dw / sw)) - 0.5)``,
  ``sx = floor(fx)``, ``fx -= sx`` (float32); before the first source column
  ``sx, fx = 0, 0``, from the last one on ``sx, fx = sw - 1, 0``.  Weights are
  ``round_half_even((1 - fx) * 2048)`` and ``round_half_even(fx * 2048)``;
* rows: the same ``fy`` but no weight clamping, only the two source rows are
  clamped to ``0 .. sh - 1``;
* horizontal sums ``H = S[sx] * a0 + S[sx + 1] * a1`` (int32, per channel),
  combined vertically as OpenCV's SIMD path does:
  ``v = ((H0 >> 4) * b0 >> 16) + ((H1 >> 4) * b1 >> 16)``,
  ``out = (v + 2) >> 2`` (always within 0..255).

Each source row is interpolated horizontally once, into one of two int32
rows that consecutive output rows share.  Where the time goes:

* horizontal pass: a gather, which Numba's vectoriser turns into slow vector
  gathers.  On x86 with AVX-512BW every 16 output values are one 64-byte
  window of the source row zero-extended to words, one ``vpermt2w`` with
  precomputed indices that puts each value's two source words side by side,
  and one ``vpmaddwd`` with the precomputed interleaved weights, giving the
  16 int32 sums directly.  Without AVX-512BW (and after the leading run of
  such blocks) groups of 4 values use a 16-byte window and ``pshufb`` (SSSE3;
  two groups per 256-bit instruction with AVX2).  Groups whose sources do not
  fit a window (strong downscales; the end of the row, where the window
  would read past it) use the scalar loop.  Only ``H >> 4`` is kept, as
  int16 (it is at most 255 * 2048 >> 4 = 32640).
* vertical pass: one block of LLVM vector IR in 16-bit lanes with
  multiply-high, as OpenCV's (Numba would promote ``int32 * int32`` to
  64-bit multiplies).

Sizes that halve exactly (the 128-px scale of a 1280x720 frame) are the
rounded 2x2 means: OpenCV switches to INTER_AREA there, which equals its
linear rule at that ratio, and :func:`_halve` computes it 16 pixels at a
time (0.26 -> 0.06 ms for that scale).

Per 1280x720 frame the detector's resizes (3 channels, default search; the
64-px scale needs none) take about 0.95 ms on one thread (Xeon with
AVX-512BW); OpenCV's take about twice as long.

Other platforms use the scalar horizontal loop (same result, slower).
"""

import functools

import numpy as np
from llvmlite import ir
from numba import njit, types, uint64
from numba.extending import intrinsic

from ._llvm import HAVE_AVX2, HAVE_AVX512BW, HAVE_SSSE3, box_sums, load_vector, store_vector
from .alloc import empty, full
from .inner import CALLED_FROM_KERNELS_ONLY
from .prefetch import prefetch_byte, prefetch_row

#: OpenCV's INTER_RESIZE_COEF_SCALE (11 fractional bits).
_COEF_SCALE = np.float32(2048)

#: Output values per horizontal group (one 128-bit pshufb + pmaddwd).
_GROUP = 4
#: Source bytes one group can draw from.
_WINDOW = 16
#: Output values per vertical block.
_VBLOCK = 32


#: Output values per AVX-512 block: 16 int32 sums from a 64-byte window.
_BLOCK = 16
_BLOCK_WINDOW = 64


@functools.lru_cache(maxsize=64)
def linear_tables(source_length, target_length, clamp_weights):
    """Source indices and the two fixed-point weights of every output position.

    Parameters
    ----------
    source_length, target_length : int
    clamp_weights : bool
        Columns (True): positions before the first or from the last source
        sample take it with weight 1.  Rows (False): the weights are kept and
        the source indices clamped.

    Returns
    -------
    first, second : ndarray of int64
        Source indices of the two taps, within the source.
    w_first, w_second : ndarray of int32
    """
    scale = 1.0 / (target_length / source_length)
    f = ((np.arange(target_length, dtype=np.float64) + 0.5) * scale - 0.5).astype(np.float32)
    first = np.floor(f).astype(np.int64)
    f = (f - first.astype(np.float32)).astype(np.float32)
    if clamp_weights:
        low = first < 0
        f[low], first[low] = 0.0, 0
        high = first >= source_length - 1
        f[high], first[high] = 0.0, source_length - 1
    # np.round rounds half to even, as OpenCV's saturate_cast<short> does.
    w_first = np.round((np.float32(1) - f) * _COEF_SCALE).astype(np.int32)
    w_second = np.round(f * _COEF_SCALE).astype(np.int32)
    second = np.clip(first + 1, 0, source_length - 1)
    first = np.clip(first, 0, source_length - 1)
    for table in (first, second, w_first, w_second):
        table.flags.writeable = False
    return first, second, w_first, w_second


@functools.lru_cache(maxsize=64)
def column_tables(source_width, target_width, channels):
    """Per output value of a flat row (``dx * channels + c``) and per group.

    Returns
    -------
    first, second : ndarray of int64
        Offsets of the two source bytes in the flat source row.
    w_first, w_second : ndarray of int32
    base : ndarray of int64, one per whole group of _GROUP values
        Start of the group's 16-byte source window.
    usable : ndarray of uint8
        1 where the group's sources fit its window and the window lies
        within the source row.
    masks : ndarray of uint8, 16 per group
        pshufb mask: value k's bytes ``first - base``, zero, ``second - base``,
        zero (0x80 writes a zero byte).
    weights : ndarray of int16, 8 per group
        ``w_first, w_second`` of each value, interleaved for pmaddwd.
    block_base : ndarray of int64
        Start of the 64-byte source window of each of the leading blocks of
        _BLOCK values (4 groups) whose sources fit it, within the row.
    picks : ndarray of int16, 32 per leading block
        ``first - base, second - base`` of each value (vpermt2w indices).
    """
    first, second, w_first, w_second = linear_tables(source_width, target_width, True)
    k = np.arange(channels)
    first = (first[:, None] * channels + k).ravel()
    second = (second[:, None] * channels + k).ravel()
    w_first = np.repeat(w_first, channels)
    w_second = np.repeat(w_second, channels)
    groups = first.size // _GROUP
    g_first = first[:groups * _GROUP].reshape(groups, _GROUP)
    g_second = second[:groups * _GROUP].reshape(groups, _GROUP)
    base = g_first.min(axis=1) if groups else np.zeros(0, np.int64)
    usable = (((g_second.max(axis=1) - base) < _WINDOW)
              & (base + _WINDOW <= source_width * channels)) if groups else np.zeros(0, bool)
    masks = np.full((groups, _GROUP, 4), 0x80, dtype=np.uint8)
    masks[:, :, 0] = np.where(usable[:, None], g_first - base[:, None], 0)
    masks[:, :, 2] = np.where(usable[:, None], g_second - base[:, None], 0)
    weights = np.empty((groups, _GROUP, 2), dtype=np.int16)
    weights[:, :, 0] = w_first[:groups * _GROUP].reshape(groups, _GROUP)
    weights[:, :, 1] = w_second[:groups * _GROUP].reshape(groups, _GROUP)
    # Blocks of _BLOCK values (4 groups): a 64-byte window, zero-extended to
    # 16-bit words, permuted (vpermt2w) into each value's two source words.
    blocks = first.size // _BLOCK
    b_first = first[:blocks * _BLOCK].reshape(blocks, _BLOCK)
    b_second = second[:blocks * _BLOCK].reshape(blocks, _BLOCK)
    b_base = b_first.min(axis=1) if blocks else np.zeros(0, np.int64)
    fits = (((b_second.max(axis=1) - b_base) < _BLOCK_WINDOW)
            & (b_base + _BLOCK_WINDOW <= source_width * channels)) if blocks else np.zeros(0, bool)
    # Only a leading run of blocks is done this way; the rest by groups.
    lead = int(np.argmin(fits)) if not fits.all() else blocks
    picks = np.empty((lead, _BLOCK, 2), dtype=np.int16)
    picks[:, :, 0] = b_first[:lead] - b_base[:lead, None]
    picks[:, :, 1] = b_second[:lead] - b_base[:lead, None]
    tables = (first.astype(np.int64), second.astype(np.int64), w_first.astype(np.int32),
              w_second.astype(np.int32), base.astype(np.int64), usable.astype(np.uint8),
              masks.ravel(), weights.ravel(), b_base[:lead].astype(np.int64), picks.ravel())
    for table in tables:
        table.flags.writeable = False
    return tables


# -- horizontal pass ---------------------------------------------------------
def _store_sums(builder, sums, dest, index, per_index=None):
    """Store ``sums >> 4`` (int32 lanes) as int16 at ``dest[index * per_index]``.

    ``per_index`` defaults to the lane count: block ``index`` of equal blocks.
    """
    lanes = sums.type.count
    i16 = ir.IntType(16)
    shifted = builder.ashr(sums, ir.Constant(sums.type, [4] * lanes))
    start = builder.mul(index, ir.Constant(index.type, per_index or lanes))
    store_vector(builder, builder.trunc(shifted, ir.VectorType(i16, lanes)), dest, start,
                 align=2)


@intrinsic
def _hgroup(typingctx, row, base, masks, weights, dest, group):
    """dest[4g:4g + 4] from the 16 bytes row[base:base + 16] (caller keeps them
    in the row): pshufb with masks[16g:16g + 16], pmaddwd with
    weights[8g:8g + 8]."""
    sig = types.void(row, base, masks, weights, dest, group)

    def codegen(context, builder, signature, args):
        row_a = context.make_array(signature.args[0])(context, builder, args[0])
        masks_a = context.make_array(signature.args[2])(context, builder, args[2])
        weights_a = context.make_array(signature.args[3])(context, builder, args[3])
        dest_a = context.make_array(signature.args[4])(context, builder, args[4])
        base, group = args[1], args[5]
        i8, i16, i32 = ir.IntType(8), ir.IntType(16), ir.IntType(32)
        v16i8, v8i16, v4i32 = ir.VectorType(i8, 16), ir.VectorType(i16, 8), ir.VectorType(i32, 4)
        module = builder.module
        pshufb = module.declare_intrinsic(
            "llvm.x86.ssse3.pshuf.b.128", fnty=ir.FunctionType(v16i8, [v16i8, v16i8]))
        pmadd = module.declare_intrinsic(
            "llvm.x86.sse2.pmadd.wd", fnty=ir.FunctionType(v4i32, [v8i16, v8i16]))

        g = builder.zext(group, ir.IntType(64)) if group.type.width < 64 else group
        window = load_vector(builder, row_a.data, base, v16i8)
        mask = load_vector(builder, masks_a.data, builder.mul(g, ir.Constant(g.type, 16)), v16i8)
        words = builder.bitcast(builder.call(pshufb, [window, mask]), v8i16)
        weight = load_vector(builder, weights_a.data, builder.mul(g, ir.Constant(g.type, 8)), v8i16)
        sums = builder.call(pmadd, [words, weight])
        _store_sums(builder, sums, dest_a.data, g)
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def _hpair(typingctx, row, base0, base1, masks, weights, dest, group):
    """Groups ``group`` and ``group + 1`` as :func:`_hgroup` does, in one
    256-bit pshufb + pmaddwd (AVX2): lane 0 holds the first group's window,
    lane 1 the second's."""
    sig = types.void(row, base0, base1, masks, weights, dest, group)

    def codegen(context, builder, signature, args):
        row_a = context.make_array(signature.args[0])(context, builder, args[0])
        masks_a = context.make_array(signature.args[3])(context, builder, args[3])
        weights_a = context.make_array(signature.args[4])(context, builder, args[4])
        dest_a = context.make_array(signature.args[5])(context, builder, args[5])
        g = args[6]
        i8, i16, i32 = ir.IntType(8), ir.IntType(16), ir.IntType(32)
        v16i8, v32i8 = ir.VectorType(i8, 16), ir.VectorType(i8, 32)
        v16i16, v8i32 = ir.VectorType(i16, 16), ir.VectorType(i32, 8)
        module = builder.module
        pshufb = module.declare_intrinsic(
            "llvm.x86.avx2.pshuf.b", fnty=ir.FunctionType(v32i8, [v32i8, v32i8]))
        pmadd = module.declare_intrinsic(
            "llvm.x86.avx2.pmadd.wd", fnty=ir.FunctionType(v8i32, [v16i16, v16i16]))

        window = builder.shuffle_vector(
            load_vector(builder, row_a.data, args[1], v16i8), load_vector(builder, row_a.data, args[2], v16i8),
            ir.Constant(ir.VectorType(i32, 32), list(range(32))))
        mask = load_vector(builder, masks_a.data, builder.mul(g, ir.Constant(g.type, 16)), v32i8)
        words = builder.bitcast(builder.call(pshufb, [window, mask]), v16i16)
        weight = load_vector(builder, weights_a.data, builder.mul(g, ir.Constant(g.type, 8)), v16i16)
        sums = builder.call(pmadd, [words, weight])
        _store_sums(builder, sums, dest_a.data, g, per_index=4)
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def _hblock(typingctx, row, base, picks, weights, dest, block):
    """dest[16b:16b + 16] from the 64 bytes row[base:base + 64] (AVX-512BW):
    zero-extend to 64 words, vpermt2w with picks[32b:32b + 32], vpmaddwd with
    weights[32b:32b + 32]."""
    sig = types.void(row, base, picks, weights, dest, block)

    def codegen(context, builder, signature, args):
        row_a = context.make_array(signature.args[0])(context, builder, args[0])
        picks_a = context.make_array(signature.args[2])(context, builder, args[2])
        weights_a = context.make_array(signature.args[3])(context, builder, args[3])
        dest_a = context.make_array(signature.args[4])(context, builder, args[4])
        b = args[5]
        i8, i16, i32 = ir.IntType(8), ir.IntType(16), ir.IntType(32)
        v64i8, v64i16 = ir.VectorType(i8, 64), ir.VectorType(i16, 64)
        v32i16, v16i32 = ir.VectorType(i16, 32), ir.VectorType(i32, 16)
        module = builder.module
        permute = module.declare_intrinsic(
            "llvm.x86.avx512.vpermi2var.hi.512",
            fnty=ir.FunctionType(v32i16, [v32i16, v32i16, v32i16]))
        pmadd = module.declare_intrinsic(
            "llvm.x86.avx512.pmaddw.d.512", fnty=ir.FunctionType(v16i32, [v32i16, v32i16]))

        words = builder.zext(load_vector(builder, row_a.data, args[1], v64i8), v64i16)
        undef = ir.Constant(v64i16, ir.Undefined)
        half = ir.VectorType(i32, 32)
        low = builder.shuffle_vector(words, undef, ir.Constant(half, list(range(32))))
        high = builder.shuffle_vector(words, undef, ir.Constant(half, list(range(32, 64))))
        index = load_vector(builder, picks_a.data, builder.mul(b, ir.Constant(b.type, 32)), v32i16)
        pairs = builder.call(permute, [low, index, high])
        weight = load_vector(builder, weights_a.data, builder.mul(b, ir.Constant(b.type, 32)), v32i16)
        sums = builder.call(pmadd, [pairs, weight])
        _store_sums(builder, sums, dest_a.data, b)
        return context.get_dummy_value()

    return sig, codegen


@njit(cache=True, nogil=True, **CALLED_FROM_KERNELS_ONLY)
def _hvalue(row, first, second, w_first, w_second, dest, e):
    dest[e] = np.int16((np.int32(row[uint64(first[e])]) * w_first[e]
                        + np.int32(row[uint64(second[e])]) * w_second[e]) >> 4)


@njit(cache=True, nogil=True, **CALLED_FROM_KERNELS_ONLY)
def _hgroups(row, first, second, w_first, w_second, base, usable, masks, weights, dest, g0,
             g1):
    """Groups g0 .. g1 - 1 one at a time: a pshufb group where its sources fit
    a window, else its 4 values by the scalar loop."""
    for g in range(g0, g1):
        if usable[g]:
            _hgroup(row, uint64(base[g]), masks, weights, dest, g)
        else:
            for e in range(g * uint64(4), g * uint64(4) + uint64(4)):
                _hvalue(row, first, second, w_first, w_second, dest, e)


@njit(cache=True, nogil=True, **CALLED_FROM_KERNELS_ONLY)
def _hrest(row, first, second, w_first, w_second, dest, e0):
    """The values past the last whole group, by the scalar loop."""
    for e in range(e0, uint64(dest.size)):
        _hvalue(row, first, second, w_first, w_second, dest, e)


@njit(cache=True, nogil=True, **CALLED_FROM_KERNELS_ONLY)
def _horizontal_avx2(row, first, second, w_first, w_second, base, usable, masks, weights,
                     block_base, picks, dest):
    groups = uint64(usable.size)
    for g in range(uint64(0), groups & ~uint64(1), uint64(2)):
        g1 = g + uint64(1)
        if usable[g] & usable[g1]:
            _hpair(row, uint64(base[g]), uint64(base[g1]), masks, weights, dest, g)
        else:
            _hgroups(row, first, second, w_first, w_second, base, usable, masks, weights, dest,
                     g, g + uint64(2))
    _hgroups(row, first, second, w_first, w_second, base, usable, masks, weights, dest,
             groups & ~uint64(1), groups)
    _hrest(row, first, second, w_first, w_second, dest, groups * uint64(4))


@njit(cache=True, nogil=True)
def _horizontal_avx512(row, first, second, w_first, w_second, base, usable, masks, weights,
                       block_base, picks, dest):
    blocks = uint64(block_base.size)
    for b in range(blocks):
        _hblock(row, uint64(block_base[b]), picks, weights, dest, b)
    groups = uint64(usable.size)
    _hgroups(row, first, second, w_first, w_second, base, usable, masks, weights, dest,
             blocks * uint64(4), groups)
    _hrest(row, first, second, w_first, w_second, dest, groups * uint64(4))


@njit(cache=True, nogil=True)
def _horizontal_ssse3(row, first, second, w_first, w_second, base, usable, masks, weights,
                      block_base, picks, dest):
    groups = uint64(usable.size)
    _hgroups(row, first, second, w_first, w_second, base, usable, masks, weights, dest,
             uint64(0), groups)
    _hrest(row, first, second, w_first, w_second, dest, groups * uint64(4))


@njit(cache=True, nogil=True)
def _horizontal_scalar(row, first, second, w_first, w_second, base, usable, masks, weights,
                       block_base, picks, dest):
    for e in range(uint64(dest.size)):
        _hvalue(row, first, second, w_first, w_second, dest, e)


# -- vertical pass -----------------------------------------------------------
@intrinsic
def _vblock(typingctx, upper, lower, w_upper, w_lower, dest, start):
    """dest[start:start + 32] from upper/lower[start:start + 32].

    ``(H >> 4)`` fits 16 bits and the weights are at most 2048, so the
    products' high halves are 16-bit multiply-high (pmulhw) lanes, as in
    OpenCV; the rest is 16-bit too.
    """
    sig = types.void(upper, lower, w_upper, w_lower, dest, start)

    def codegen(context, builder, signature, args):
        upper_a = context.make_array(signature.args[0])(context, builder, args[0])
        lower_a = context.make_array(signature.args[1])(context, builder, args[1])
        dest_a = context.make_array(signature.args[4])(context, builder, args[4])
        start = args[5]
        i8, i16, i32 = ir.IntType(8), ir.IntType(16), ir.IntType(32)
        words = ir.VectorType(i32, _VBLOCK)
        halves = ir.VectorType(i16, _VBLOCK)
        bytes_ = ir.VectorType(i8, _VBLOCK)

        def splat(value, vector_type):
            element = vector_type.element
            value = builder.trunc(value, element) if value.type.width > element.width else value
            vector = builder.insert_element(ir.Constant(vector_type, ir.Undefined), value,
                                            ir.Constant(i32, 0))
            return builder.shuffle_vector(vector, ir.Constant(vector_type, ir.Undefined),
                                          ir.Constant(ir.VectorType(i32, _VBLOCK), [0] * _VBLOCK))

        def const(vector_type, value):
            return ir.Constant(vector_type, [value] * _VBLOCK)

        def tap(array, weight):
            h = load_vector(builder, array.data, start, halves, align=2)
            # mulhi: (sext(h) * sext(w)) >> 16, truncated back to 16 bits.
            product = builder.mul(builder.sext(h, words), builder.sext(weight, words))
            return builder.trunc(builder.ashr(product, const(words, 16)), halves)

        v = builder.add(tap(upper_a, splat(args[2], halves)), tap(lower_a, splat(args[3], halves)))
        v = builder.ashr(builder.add(v, const(halves, 2)), const(halves, 2))
        store_vector(builder, builder.trunc(v, bytes_), dest_a.data, start)
        return context.get_dummy_value()

    return sig, codegen


@njit(cache=True, nogil=True, **CALLED_FROM_KERNELS_ONLY)
def _vertical(upper, lower, w_upper, w_lower, dest):
    n = uint64(dest.size)
    blocks = n // uint64(_VBLOCK)
    for b in range(blocks):
        _vblock(upper, lower, w_upper, w_lower, dest, b * uint64(_VBLOCK))
    for i in range(blocks * uint64(_VBLOCK), n):
        v = ((np.int32(upper[i]) * w_upper) >> 16) + ((np.int32(lower[i]) * w_lower) >> 16)
        # The two weights sum to 2048, so v stays within 0..255.
        dest[i] = np.uint8((v + 2) >> 2)


# -- driver --------------------------------------------------------------------
@njit(cache=True, nogil=True, **CALLED_FROM_KERNELS_ONLY)
def _find(held, source):
    if held[0] == source:
        return 0
    if held[1] == source:
        return 1
    return -1


#: What this machine can run, fixed at import.  They are compile-time
#: constants of _horizontal, so the branches of paths the CPU lacks are pruned
#: before typing (their instructions may not exist here); the cached machine
#: code stays valid because Numba keys its cache by the host CPU.
_CAN_AVX512BW, _CAN_AVX2, _CAN_SSSE3 = HAVE_AVX512BW, HAVE_AVX2, HAVE_SSSE3

def _best_path():
    """The best path the ``HAVE_*`` flags allow (the tests switch them off)."""
    return 0 if HAVE_AVX512BW else 1 if HAVE_AVX2 else 2 if HAVE_SSSE3 else 3


#: The best path this CPU has: the only one :func:`_resize` compiles.
NATIVE_PATH = _best_path()


@njit(cache=True, nogil=True)
def _horizontal(path, row, first, second, w_first, w_second, base, usable, masks, weights,
                block_base, picks, dest):
    """The horizontal pass of ``path`` (0 AVX-512BW, 1 AVX2, 2 SSSE3, 3 scalar)."""
    if _CAN_AVX512BW:
        if path == 0:
            _horizontal_avx512(row, first, second, w_first, w_second, base, usable, masks,
                               weights, block_base, picks, dest)
            return
    if _CAN_AVX2:
        if path <= 1:
            _horizontal_avx2(row, first, second, w_first, w_second, base, usable, masks,
                             weights, block_base, picks, dest)
            return
    if _CAN_SSSE3:
        if path <= 2:
            _horizontal_ssse3(row, first, second, w_first, w_second, base, usable, masks,
                              weights, block_base, picks, dest)
            return
    _horizontal_scalar(row, first, second, w_first, w_second, base, usable, masks, weights,
                       block_base, picks, dest)


#: The horizontal pass of :data:`NATIVE_PATH`, chosen here, so the other paths
#: are never compiled.  Not a kernel choosing it: Numba would compile that
#: kernel too and optimise the chosen pass's code again in it (0.1-0.2 s).
_horizontal_native = (_horizontal_avx512, _horizontal_avx2, _horizontal_ssse3,
                      _horizontal_scalar)[NATIVE_PATH]


@njit(cache=True, nogil=True, **CALLED_FROM_KERNELS_ONLY)
def _row_slots(held, upper, lower):
    """Where output row taps ``upper`` and ``lower`` are kept among the two
    horizontal rows, and whether each must be computed first (``held`` is
    updated).  Consecutive output rows share source rows."""
    slot_upper = _find(held, upper)
    slot_lower = _find(held, lower)
    new_upper = slot_upper < 0
    new_lower = False
    if new_upper:
        # Never evict the row the other tap sits in.
        slot_upper = 1 if slot_lower == 0 else 0
        held[slot_upper] = upper
    if slot_lower < 0:
        if lower == upper:
            slot_lower = slot_upper
        else:
            slot_lower = 1 - slot_upper
            held[slot_lower] = lower
            new_lower = True
    return slot_upper, new_upper, slot_lower, new_lower


#: Output rows ahead whose lower source row is asked for (see
#: :mod:`fastdet.kernels.prefetch`).
_PREFETCH_ROWS = 2


@njit(cache=True, nogil=True)
def _resize(src, first, second, w_first, w_second, base, usable, masks, weights, block_base,
            picks, y_first, y_second, w_y_first, w_y_second, out):
    """The resize with this CPU's best horizontal path, the only one compiled."""
    rows = empty((2, out.shape[1]), dtype=np.int16)
    held = full(2, -1, np.int64)
    last = out.shape[0] - 1
    for dy in range(out.shape[0]):
        upper, lower = y_first[dy], y_second[dy]
        prefetch_row(src, y_second[min(dy + _PREFETCH_ROWS, last)])
        slot_upper, new_upper, slot_lower, new_lower = _row_slots(held, upper, lower)
        if new_upper:
            _horizontal_native(src[upper], first, second, w_first, w_second, base, usable,
                               masks, weights, block_base, picks, rows[slot_upper])
        if new_lower:
            _horizontal_native(src[lower], first, second, w_first, w_second, base, usable,
                               masks, weights, block_base, picks, rows[slot_lower])
        _vertical(rows[slot_upper], rows[slot_lower], w_y_first[dy], w_y_second[dy], out[dy])


@njit(cache=True, nogil=True)
def _resize_path(path, src, first, second, w_first, w_second, base, usable, masks, weights,
                 block_base, picks, y_first, y_second, w_y_first, w_y_second, out):
    """:func:`_resize` with any path the CPU has (tests compare every path)."""
    rows = empty((2, out.shape[1]), dtype=np.int16)
    held = full(2, -1, np.int64)
    for dy in range(out.shape[0]):
        upper, lower = y_first[dy], y_second[dy]
        slot_upper, new_upper, slot_lower, new_lower = _row_slots(held, upper, lower)
        if new_upper:
            _horizontal(path, src[upper], first, second, w_first, w_second, base, usable,
                        masks, weights, block_base, picks, rows[slot_upper])
        if new_lower:
            _horizontal(path, src[lower], first, second, w_first, w_second, base, usable,
                        masks, weights, block_base, picks, rows[slot_lower])
        _vertical(rows[slot_upper], rows[slot_lower], w_y_first[dy], w_y_second[dy], out[dy])


# -- exact halving --------------------------------------------------------------
#: Output bytes per halving block: 16 pixels of 3 channels.
_HALF_BLOCK = 48


def _halve_block(channels):
    """An intrinsic ``block(upper, lower, start, dest, out)`` writing
    ``_HALF_BLOCK`` output bytes ``dest[out:]``: the means
    ``(a + b + c + d + 2) >> 2`` of 2x2 source pixels, from the
    ``2 * _HALF_BLOCK`` bytes at ``upper[start:]`` and ``lower[start:]``.

    One block of LLVM vector IR: the 2x2 sums of
    :func:`fastdet.kernels._llvm.box_sums`, then round and narrow.
    """
    n_out = _HALF_BLOCK
    n_in = 2 * n_out

    def codegen(context, builder, signature, args):
        upper, lower, dest = [context.make_array(signature.args[k])(context, builder, args[k]).data
                              for k in (0, 1, 3)]
        start, out = args[2], args[4]
        bytes_in = ir.VectorType(ir.IntType(8), n_in)
        words_out = ir.VectorType(ir.IntType(16), n_out)
        total = box_sums(builder, [load_vector(builder, upper, start, bytes_in),
                                   load_vector(builder, lower, start, bytes_in)], 2, channels)
        two = ir.Constant(words_out, [2] * n_out)
        mean = builder.lshr(builder.add(total, two), two)
        store_vector(builder, builder.trunc(mean, ir.VectorType(ir.IntType(8), n_out)), dest, out)
        return context.get_dummy_value()

    def block(typingctx, upper, lower, start, dest, out):
        return types.void(upper, lower, start, dest, out), codegen

    block.__name__ = block.__qualname__ = f"_halve{channels}_block"
    return intrinsic(block)


_halve3_block = _halve_block(3)


@njit(cache=True, nogil=True)
def _halve(src, channels, out):
    """``out`` = ``src`` halved in both directions, as (H, W * C) row views
    with contiguous rows: the rounded mean of every 2x2 block of pixels.

    When the size halves exactly OpenCV's INTER_LINEAR takes its INTER_AREA
    path, which is this mean; the linear rule gives it too (weights 1024 and
    1024, every shift exact).  Blocks of 16 pixels for 3 channels, the rest
    one value at a time.
    """
    n = uint64(out.shape[1])
    c = uint64(channels)
    step = uint64(_HALF_BLOCK)
    blocks = n // step if channels == 3 else uint64(0)
    ahead = np.int64(2 * _PREFETCH_ROWS)
    last = np.int64(src.shape[0] - 2)
    for dy in range(out.shape[0]):
        upper = src[2 * dy]
        lower = src[2 * dy + 1]
        row = out[dy]
        next_upper = src[min(2 * dy + ahead, last)]
        next_lower = src[min(2 * dy + ahead + 1, last + 1)]
        for k in range(blocks):
            # One 64-byte line of each source row per 96 bytes read: every line.
            prefetch_byte(next_upper, k * (step + step))
            prefetch_byte(next_lower, k * (step + step))
            _halve3_block(upper, lower, k * (step + step), row, k * step)
        for i in range(blocks * step, n):
            s = (i // c) * (c + c) + i % c
            total = (np.int32(upper[s]) + np.int32(upper[s + c]) + np.int32(lower[s])
                     + np.int32(lower[s + c]))
            row[i] = np.uint8((total + 2) >> 2)


def resize_linear(image, size, out=None, rows=None):
    """Resize a uint8 image to ``size`` exactly as ``cv2.resize(..., INTER_LINEAR)``.

    Parameters
    ----------
    image : ndarray of uint8, shape (H, W, C)
        May be a strided view (a region of a frame); rows with contiguous
        pixels are read in place.
    size : tuple of int
        ``(width, height)`` of the result, as in OpenCV.
    out : ndarray of uint8, shape (height, width, C), C-contiguous, optional
    rows : tuple of int, optional
        ``(first, stop)``: compute only these rows of the result (the others
        of ``out`` are left as they are), each exactly as in the whole
        result.  Threads resize bands of one image this way.

    Returns
    -------
    ndarray of uint8, shape (height, width, C)
    """
    if not isinstance(image, np.ndarray) or image.dtype != np.uint8 or image.ndim != 3:
        raise ValueError(f"expected a uint8 (H, W, C) image, got "
                         f"{getattr(image, 'dtype', type(image))} {getattr(image, 'shape', '')}")
    if len(size) != 2:
        raise ValueError(f"size must be (width, height), got {size!r}")
    if out is None:
        # Negative sizes are refused by RowResizer, with the sizes named.
        out = np.empty((max(0, int(size[1])), max(0, int(size[0])), image.shape[2]), np.uint8)
    resizer = RowResizer(image.shape, size, out)
    resizer(image, *((0, out.shape[0]) if rows is None else rows))
    return out


class RowResizer:
    """:func:`resize_linear` of images of one shape to one size, into one array,
    checked and sized once; each call resizes some rows of the result.

    For the detector's scales (see :class:`~fastdet.kernels.score.WindowRowScorer`).

    Parameters
    ----------
    source_shape : tuple of int
        ``(H, W, C)`` of the uint8 images the calls take (they may be strided
        views whose pixels are contiguous, like :func:`resize_linear`'s).
    size : tuple of int
        ``(width, height)`` of the result.
    out : ndarray of uint8, shape (height, width, C), C-contiguous
    """

    def __init__(self, source_shape, size, out):
        source_h, source_w, channels = (int(n) for n in source_shape)
        width, height = int(size[0]), int(size[1])
        if width < 1 or height < 1 or source_h < 1 or source_w < 1 or channels < 1:
            raise ValueError(f"cannot resize a {source_w}x{source_h}x{channels} image to "
                             f"{width}x{height}")
        shape = (height, width, channels)
        if (not isinstance(out, np.ndarray) or out.shape != shape or out.dtype != np.uint8
                or not out.flags.c_contiguous or not out.flags.writeable):
            raise ValueError(f"out must be a writeable C-contiguous uint8 array of shape {shape}")
        self.source_shape = (source_h, source_w, channels)
        self.out = out
        self._rows = out.reshape(height, width * channels)
        self._kind = "copy"
        if (source_h, source_w) == (2 * height, 2 * width):
            self._kind = "halve"
        elif (source_h, source_w) != (height, width):
            self._kind = "linear"
            self._x_tables = column_tables(source_w, width, channels)
            self._y_tables = linear_tables(source_h, height, False)
            self._path = _best_path()

    def __call__(self, image, first, stop):
        """Resize rows ``first`` .. ``stop - 1`` of the result of ``image`` into :attr:`out`."""
        call = self.bind(image, first, stop)
        if call is not None:
            call[0](*call[1])

    def bind(self, image, first, stop):
        """``(function, arguments)`` of what ``self(image, first, stop)`` runs, or None
        when it resizes no row.

        A caller that resizes the same rows of the same array, refilled in place,
        frame after frame makes this once and calls ``function(*arguments)``: the
        checks, views and table slices above the kernel are then not redone (Python
        run with the GIL held, which a thread scoring another frame waits for).
        Each call reads ``image`` as it is then (an image whose rows are not
        contiguous is copied at each call, not once here).
        """
        if image.shape != self.source_shape or image.dtype != np.uint8:
            raise ValueError(f"expected a uint8 image of shape {self.source_shape}, "
                             f"got {image.dtype} {image.shape}")
        height = self.out.shape[0]
        first, stop = max(0, int(first)), min(height, int(stop))
        if first >= stop:
            return None
        if self._kind == "copy":
            return np.copyto, (self.out[first:stop], image[first:stop])
        source_h, source_w, channels = self.source_shape
        if image.strides[2] != 1 or image.strides[1] != channels:
            # Its rows are not contiguous: reshaping would copy them, once.
            return self._call_on_a_copy, (image, first, stop)
        # Rows of a column-sliced region stay contiguous: a (H, W * C) view.
        source = image.reshape(source_h, source_w * channels)
        dest = self._rows[first:stop]
        if self._kind == "halve":
            return _halve, (source[2 * first:2 * stop], channels, dest)
        y_tables = [table[first:stop] for table in self._y_tables]
        if self._path == NATIVE_PATH:
            return _resize, (source, *self._x_tables, *y_tables, dest)
        return _resize_path, (self._path, source, *self._x_tables, *y_tables, dest)

    def _call_on_a_copy(self, image, first, stop):
        """``self(image, first, stop)`` through a contiguous copy of ``image``."""
        function, arguments = self.bind(np.ascontiguousarray(image), first, stop)
        function(*arguments)
