"""Per-pixel colour kernels: box-averaged image and histogram-weight tile sums.

Both feed the colour part of a window's score (see :mod:`fastdet.kernels.score`):

* spatial features are the window box-averaged by an integer factor, i.e. an
  aligned crop of the whole box-averaged image;
* the colour histogram's share of the score is linear in the per-pixel bin
  indicators, so it equals the window sum of a per-pixel weight
  ``sum_c lut[c, value_c]``.  Windows are made of whole tiles (the tile side
  divides both the window side and the window step), so per-tile sums are all
  a frame needs; :func:`fastdet.kernels.score.add_tile_window_sums` adds them
  up per window.

One call produces both, one band of tile rows at a time so the box pass reads
rows the tile pass has just brought into cache.  Colour images always have
three channels here, which the loops hard-code.  Indices are unsigned: Numba's
negative-index wraparound would otherwise get in LLVM's way.

Where the time goes (one thread, Xeon with AVX-512; the detector's five
scale images of a 1280x720 frame, 0.83 M pixels, tiles of 16 to 64 and box
factor 2: 0.42 ms, about 0.5 ns per pixel, of which the tile sums take 0.23):

* Tile sums with the detector's lut (:func:`_bin_column_sums`): for 32 bins
  or fewer a weight only depends on ``value >> 3``, so each channel's weights
  are a 32-entry table, two 512-bit registers, and 16 lookups are one
  vpermi2ps.  Per 16 pixels of a row: one 64-byte load, vpermd and vpshufb to
  give each pixel a 32-bit lane, one 16-bit shift, two 32-bit shifts, three
  vpermi2ps and three adds, 11 instructions balanced over the two 512-bit
  ports (about 0.21-0.25 ns per pixel).  Each 16 columns' sums stay in a
  register down the tile row; tiles then add their columns.  Slower variants:
  four 16-byte loads instead of one load and vpermd (10-15 %); one vpshufb
  per channel instead of the shifts (about 5 %); a masked load that never
  reads past the block (15 %); rows outer with the column sums in memory
  (5-10 %); four partial sums per tile in the column pass (10 %).
* Tile sums with the detector's lut and AVX2 alone
  (:func:`_bin_column_sums_avx2`): the same 32-entry tables, looked up by
  vpshufb, 16 entries per 128-bit lane: a channel's 32 float weights are four
  byte planes of two halves, and per 32 pixels of a row each plane is two
  vpshufb and an or, then eight unpacks put the planes' bytes back together
  as floats.  About 60 shuffles per 32 pixels, on the two shuffle pipes of
  AMD's cores: 0.47 ns per pixel against 0.76-0.80 for the scalar path on an
  AMD EPYC (Zen 4 with AVX-512 hidden, AVX2 code, 2.9 GHz; 1344 x 128 pixels,
  tiles of 16 and 32, one thread).  Each column adds the same weights in the
  same order as the AVX-512 path, so the two give the same sums.  Slower
  AVX2 formulations, measured on a Zen 3 EPYC: four vpermps and three blends
  per channel and 8 pixels (0.93 ns against 0.80; its twelve table registers
  spill), 8-lane gathers from the lut (1.51 ns).
* Tile sums with any other lut (or without AVX2): three scalar table
  lookups per pixel.  Vector gathers are slow on this CPU (over 1 ns per
  lookup), and LLVM cannot prove the table unaliased anyway, so they stay
  scalar (about 0.55 ms for a 1280x720 frame, tiles of 16, generic build on
  an AMD Zen 4) and the work is cutting instructions: four pixels (12 bytes)
  come from three 32-bit words (split with shifts) plus three single bytes,
  and four columns' sums stay in registers down the tile row.  They add in
  the bin-table paths' order (each column over the rows in turn, then each
  tile's columns), so a lut with a bin table gets the same sums on every CPU;
  a fixed tree of adds per tile, as before, was no faster (0.55 against
  0.52 ms) and rounded its own way.  No reassociating fastmath here: LLVM
  would then pick the order.  (A combined table for two channels, 256 KB,
  halves the lookups but after building it saved only 5-7 %.)
* The box mean of 16 output pixels is one block of LLVM vector IR
  (:func:`_box_block`, factors 1, 2 and 4): widen each row run to 16 bits,
  add the rows, pick each output pixel's source pixels with constant shuffles,
  add, convert, scale (about 0.25 ns per pixel for factor 2).  Numba's loop
  vectoriser only manages gathers or long shuffle chains for these strided
  patterns, and its SLP vectoriser is off.  LLVM runs the block on 512-bit
  registers here, which lowers the core clock a little for the scalar tile
  loop as well; 256-bit versions of the block were slower overall.

The box image is exact (sums of bytes, one rounding in the final scale).  The
tile sums are float32 sums in one fixed order on every path, so they differ
from a float64 reference only by float32 rounding.
"""

import sys

import numpy as np
from llvmlite import ir
from numba import njit, types, uint64
from numba.core import cgutils
from numba.extending import intrinsic

from ._llvm import HAVE_AVX2, HAVE_AVX512BW, box_sums, load_vector, store_vector
from .alloc import empty
from .inner import CALLED_FROM_KERNELS_ONLY
from .views import flat as flat_view

_C = uint64(3)
_BYTE = uint64(255)
# Channel c's table starts at lut_flat[256 * c].
_LUT1 = uint64(256)
_LUT2 = uint64(512)

#: Pixels are split from whole 32-bit words only on little-endian machines.
_LITTLE_ENDIAN = sys.byteorder == "little"

#: Tile-sum paths: the bin-table vector paths (AVX-512BW, AVX2), and the table
#: lookups per pixel that work for any lut.
PATH_AVX512 = 0
PATH_SCALAR = 1
PATH_AVX2 = 2

#: The bin-table path needs each channel's lut constant on aligned runs of
#: 2**_BIN_SHIFT values (true of the detector's lut for 1, 2, 4, ... 32 bins):
#: a weight is then entry ``value >> _BIN_SHIFT`` of a _BINS-entry table,
#: two 512-bit registers.
_BIN_SHIFT = 3
_BINS = 256 >> _BIN_SHIFT
#: Pixels per bin-table block: one 32-bit lane each (48 bytes in).
_PIXEL_BLOCK = 16


@intrinsic
def _load_u32(typingctx, flat, offset):
    """The 4 bytes ``flat[offset:offset + 4]`` as one native-endian uint32
    (unaligned load; the caller keeps it in bounds)."""
    sig = types.uint32(flat, offset)

    def codegen(context, builder, signature, args):
        data = context.make_array(signature.args[0])(context, builder, args[0]).data
        return load_vector(builder, data, args[1], ir.IntType(32))

    return sig, codegen


#: Output pixels per box block: 16 * factor * 3 bytes of each of factor rows.
_BOX_BLOCK = 16


def _box_block(factor):
    """An intrinsic ``block(flat, top, row_bytes, dest, out)`` that writes the
    ``factor x factor`` box means of _BOX_BLOCK output pixels,
    dest[out + 3 * o + c], from the ``factor`` rows starting at flat[top],
    flat[top + row_bytes], ... (reading ``3 * factor * _BOX_BLOCK`` bytes of each).

    One block of LLVM vector IR: the box sums of
    :func:`fastdet.kernels._llvm.box_sums` (rows widened to 16 bits and
    added, each output pixel's ``factor`` columns picked by constant shuffles
    and added), converted and scaled.  Numba's loop vectoriser only manages slow
    gathers or long shuffle chains for these strided patterns (and its SLP
    vectoriser is off).  Sums of up to 16 x 16 bytes fit 16 bits.
    """
    assert 1 <= factor <= 16
    n_in, n_out = 3 * factor * _BOX_BLOCK, 3 * _BOX_BLOCK
    # Same rounding as sum * np.float32(1 / factor**2) in float32.
    scale = float(np.float32(1.0 / (factor * factor)))

    def codegen(context, builder, signature, args):
        flat = context.make_array(signature.args[0])(context, builder, args[0])
        dest = context.make_array(signature.args[3])(context, builder, args[3])
        top, row_bytes, out = args[1], args[2], args[4]
        f32 = ir.FloatType()
        bytes_in = ir.VectorType(ir.IntType(8), n_in)
        rows = [load_vector(builder, flat.data,
                            builder.add(top, builder.mul(row_bytes,
                                                         ir.Constant(row_bytes.type, dy))),
                            bytes_in)
                for dy in range(factor)]
        total = box_sums(builder, rows, factor, 3)
        floats = ir.VectorType(f32, n_out)
        mean = builder.fmul(builder.uitofp(total, floats), ir.Constant(floats, [scale] * n_out))
        store_vector(builder, mean, dest.data, out, align=4)
        return context.get_dummy_value()

    def block(typingctx, flat, top, row_bytes, dest, out):
        return types.void(flat, top, row_bytes, dest, out), codegen

    block.__name__ = block.__qualname__ = f"_box{factor}_block"
    return intrinsic(block)


_box1_block = _box_block(1)
_box2_block = _box_block(2)
_box4_block = _box_block(4)


# -- tile sums ---------------------------------------------------------------
@njit(cache=True, nogil=True, **CALLED_FROM_KERNELS_ONLY)
def _pixel_weight(flat, lut, i):
    """lut[0, v0] + lut[1, v1] + lut[2, v2] of the pixel at flat[i:i + 3]."""
    return ((lut[uint64(flat[i])] + lut[_LUT1 + uint64(flat[i + uint64(1)])])
            + lut[_LUT2 + uint64(flat[i + uint64(2)])])


@njit(cache=True, nogil=True, inline="always")
def _four_weights(flat, lut, i):
    """The weights of the 4 pixels at flat[i:i + 12], each ``(w0 + w1) + w2``."""
    if not _LITTLE_ENDIAN:
        return (_pixel_weight(flat, lut, i), _pixel_weight(flat, lut, i + uint64(3)),
                _pixel_weight(flat, lut, i + uint64(6)), _pixel_weight(flat, lut, i + uint64(9)))
    # Bytes v0 v1 v2 | v0 v1 v2 | v0 v1 v2 | v0 v1 v2: bytes 2, 6 and 10 are
    # loaded on their own (cheaper than a shift and a mask), the rest split
    # from the three words at bytes 0, 4 and 8.  The byte loads come first so
    # that LLVM does not turn them back into extractions from the words.
    v2 = uint64(flat[i + uint64(2)])
    v6 = uint64(flat[i + uint64(6)])
    v10 = uint64(flat[i + uint64(10)])
    a = uint64(_load_u32(flat, i))
    b = uint64(_load_u32(flat, i + uint64(4)))
    c = uint64(_load_u32(flat, i + uint64(8)))
    return ((lut[a & _BYTE] + lut[_LUT1 + ((a >> uint64(8)) & _BYTE)]) + lut[_LUT2 + v2],
            (lut[a >> uint64(24)] + lut[_LUT1 + (b & _BYTE)])
            + lut[_LUT2 + ((b >> uint64(8)) & _BYTE)],
            (lut[v6] + lut[_LUT1 + (b >> uint64(24))]) + lut[_LUT2 + (c & _BYTE)],
            (lut[(c >> uint64(8)) & _BYTE] + lut[_LUT1 + v10]) + lut[_LUT2 + (c >> uint64(24))])


# -- tile sums from a bin table (AVX-512) -------------------------------------
#: Bytes a block reads: one 64-byte load, of which the block's 48 bytes are used.
_BLOCK_READ = 64
#: 32-bit words of the load moved into each 128-bit lane (vpermd): block
#: bytes 0-15, 12-27, 24-39 and 32-47, i.e. pixels 0-3, 4-7 and 8-11 from
#: byte 0 of their lane and pixels 12-15 from byte 4.
_LANE_WORDS = [0, 1, 2, 3, 3, 4, 5, 6, 6, 7, 8, 9, 8, 9, 10, 11]
_LANE_SKIP = [0, 0, 0, 4]


def _expand_pixels():
    """vpshufb mask giving each pixel of a block its own 32-bit lane: channels
    0-2 in bytes 0-2, zero in byte 3 (laid out as _LANE_WORDS)."""
    mask = []
    for skip in _LANE_SKIP:
        for k in range(4):
            mask += [skip + 3 * k, skip + 3 * k + 1, skip + 3 * k + 2, 0x80]
    return mask


def _column_sum_arguments(context, builder, signature, args):
    """A column-sums intrinsic's arguments ``(flat, start, row_bytes, rows,
    blocks, table, sums)`` as ``(flat, table, sums)`` arrays and the four
    integers."""
    arrays = tuple(context.make_array(signature.args[k])(context, builder, args[k])
                   for k in (0, 5, 6))
    return arrays, args[1:5]


@intrinsic
def _bin_column_sums(typingctx, flat, start, row_bytes, rows, blocks, table, sums):
    """sums[16k + j] = weight sum over ``rows`` rows of pixel column 16k + j,
    for the ``blocks`` blocks of _PIXEL_BLOCK pixels of the rows starting at
    flat[start], flat[start + row_bytes], ...  Each block reads _BLOCK_READ
    bytes of every row (16 past its own): the caller keeps them in ``flat``.

    ``table[32c + b]`` is channel c's weight for ``value >> 3 == b``.  Per
    block and row: one 64-byte load; vpermd and vpshufb give each pixel a
    32-bit lane; a 16-bit shift by 3 leaves ``value >> 3`` in the low 5 bits
    of every byte (the bits shifted in from the next byte land above them);
    channel c's lane index is that lane shifted right by 8c (vpermi2ps reads
    only the low 5 bits of an index) and one vpermi2ps looks its 16 weights
    up in the two registers of channel c's table.  A block's column sums stay
    in a register over the rows.  That is 11 instructions per 16 pixels, the
    5 shuffles and 6 shifts and adds balanced over the two 512-bit ports.
    """
    sig = types.void(flat, start, row_bytes, rows, blocks, table, sums)

    def codegen(context, builder, signature, args):
        (flat_a, table_a, sums_a), (start, row_bytes, rows, blocks) = _column_sum_arguments(
            context, builder, signature, args)
        i8, i16, i32, f32 = ir.IntType(8), ir.IntType(16), ir.IntType(32), ir.FloatType()
        v64i8, v32i16 = ir.VectorType(i8, 64), ir.VectorType(i16, 32)
        v16i32, v16f32 = ir.VectorType(i32, 16), ir.VectorType(f32, 16)
        module = builder.module
        pshufb = module.declare_intrinsic(
            "llvm.x86.avx512.pshuf.b.512", fnty=ir.FunctionType(v64i8, [v64i8, v64i8]))
        permute = module.declare_intrinsic(
            "llvm.x86.avx512.vpermi2var.ps.512",
            fnty=ir.FunctionType(v16f32, [v16f32, v16i32, v16f32]))

        def const(value):
            return ir.Constant(start.type, value)

        halves = [(load_vector(builder, table_a.data, const(_BINS * c), v16f32, align=4),
                   load_vector(builder, table_a.data, const(_BINS * c + 16), v16f32, align=4))
                  for c in range(3)]
        lane_words = ir.Constant(v16i32, _LANE_WORDS)
        expand = ir.Constant(v64i8, _expand_pixels())
        bin_shift = ir.Constant(v32i16, [_BIN_SHIFT] * 32)
        total = cgutils.alloca_once(builder, v16f32)
        with cgutils.for_range(builder, blocks) as block:
            top = builder.add(start, builder.mul(block.index, const(3 * _PIXEL_BLOCK)))
            builder.store(ir.Constant(v16f32, [0.0] * 16), total)
            with cgutils.for_range(builder, rows) as row:
                at = builder.add(top, builder.mul(row.index, row_bytes))
                words = builder.bitcast(load_vector(builder, flat_a.data, at, v64i8), v16i32)
                laid_out = builder.shuffle_vector(words, ir.Constant(v16i32, ir.Undefined),
                                                  lane_words)
                bins = builder.lshr(builder.bitcast(laid_out, v32i16), bin_shift)
                pixels = builder.bitcast(
                    builder.call(pshufb, [builder.bitcast(bins, v64i8), expand]), v16i32)
                weight = None
                for c in range(3):
                    index = pixels if c == 0 else builder.lshr(
                        pixels, ir.Constant(v16i32, [8 * c] * 16))
                    looked_up = builder.call(permute, [halves[c][0], index, halves[c][1]])
                    weight = looked_up if weight is None else builder.fadd(weight, looked_up)
                builder.store(builder.fadd(builder.load(total), weight), total)
            store_vector(builder, builder.load(total), sums_a.data,
                         builder.mul(block.index, const(_PIXEL_BLOCK)), align=4)
        return context.get_dummy_value()

    return sig, codegen


def bin_table(lut):
    """The bin-table paths' weights of a lut, or ``None`` if it has none.

    Parameters
    ----------
    lut : array_like of float32, shape (3, 256)

    Returns
    -------
    ndarray of float32, shape (3 * 32,) or None
        ``table[32c + b] = lut[c, 8b]`` where each channel of ``lut`` is
        constant on aligned runs of 8 values (the detector's lut for 32 bins
        or fewer); ``None`` otherwise (a NaN equals nothing, so a lut with
        one has no table).  Worked out in NumPy once per lut, so the kernel
        compiles no check of its own.
    """
    lut = np.asarray(lut, dtype=np.float32)
    runs = lut[:, ::1 << _BIN_SHIFT]
    if not np.array_equal(lut, np.repeat(runs, 1 << _BIN_SHIFT, axis=1)):
        return None
    return np.ascontiguousarray(runs.reshape(-1))


@njit(cache=True, nogil=True, inline="always")
def _finish_tile_row(flat, row, lut, t, start, done, columns, out):
    """The rest of a tile row: the column sums from column ``done`` to the last
    tile's end one pixel at a time (the same operations, in the same order, as
    a vector block's lane: each pixel's ``(w0 + w1) + w2``, added over the
    rows in turn), then each tile's columns added in order.  Four columns at
    once keep their sums in registers down the tile row; their pixels come
    from three 32-bit words."""
    covered = uint64(out.size) * t
    fours = done + (covered - min(done, covered)) // uint64(4) * uint64(4)
    for x in range(done, fours, uint64(4)):
        s0 = s1 = s2 = s3 = np.float32(0.0)
        for dy in range(t):
            w0, w1, w2, w3 = _four_weights(flat, lut, start + dy * row + x * _C)
            s0 += w0
            s1 += w1
            s2 += w2
            s3 += w3
        columns[x] = s0
        columns[x + uint64(1)] = s1
        columns[x + uint64(2)] = s2
        columns[x + uint64(3)] = s3
    for x in range(fours, covered):
        i = start + x * _C
        total = np.float32(0.0)
        for dy in range(t):
            total += _pixel_weight(flat, lut, i + dy * row)
        columns[x] = total
    for tx in range(uint64(out.size)):
        total = np.float32(0.0)
        for dx in range(tx * t, tx * t + t):
            total += columns[dx]
        out[tx] = total


@njit(cache=True, nogil=True, **CALLED_FROM_KERNELS_ONLY)
def _tile_row_bins(flat, row_bytes, lut, table, tile, y0, columns, out):
    """One tile row's sums with a bin table: sums of each image column over
    the tile row into ``columns`` (16-pixel vector blocks, then the columns of
    whole tiles past the last block one pixel at a time), then each tile's
    columns added in order."""
    t = uint64(tile)
    row = uint64(row_bytes)
    covered = uint64(out.size) * t
    start = uint64(y0) * row
    # Blocks whose reads stay in the image on the tile row's last row; only
    # the bottom tile row of an image can lose its last block this way.
    last_row = start + (t - uint64(1)) * row
    room = uint64(flat.size) - last_row
    fit = (room - uint64(_BLOCK_READ)) // uint64(3 * _PIXEL_BLOCK) + uint64(1) \
        if room >= uint64(_BLOCK_READ) else uint64(0)
    blocks = min(covered // uint64(_PIXEL_BLOCK), fit)
    _bin_column_sums(flat, start, row, t, blocks, table, columns)
    _finish_tile_row(flat, row, lut, t, start, blocks * uint64(_PIXEL_BLOCK), columns, out)


# -- tile sums from a bin table (AVX2) ----------------------------------------
#: Pixels per AVX2 bin-table block: 16 in each 128-bit lane, 96 bytes read
#: (the block's own: no read past it).
_AVX2_BLOCK = 32


def _i8(values):
    """Byte constants as LLVM wants them: signed."""
    return [v - 256 if v > 127 else v for v in values]


def _deinterleave_masks():
    """vpshufb masks ``[c][s]``: channel c's byte of each of a lane's 16
    pixels from the lane's source vector s (bytes 16s .. 16s + 15 of the 48
    the lane holds), pixel p in byte p; 0x80 writes a zero byte."""
    return [[_i8([(3 * p + c) % 16 if (3 * p + c) // 16 == s else 0x80 for p in range(16)] * 2)
             for s in range(3)] for c in range(3)]


def _lane_interleave(count, half):
    """shufflevector indices of the x86 unpack (lo: half 0, hi: half 1) of two
    vectors of ``count`` elements, which interleaves within each 128-bit lane."""
    per_lane = count // 2
    indices = []
    for lane in range(2):
        for i in range(half * per_lane // 2, (half + 1) * per_lane // 2):
            indices += [lane * per_lane + i, count + lane * per_lane + i]
    return indices


@intrinsic
def _bin_column_sums_avx2(typingctx, flat, start, row_bytes, rows, blocks, table, sums):
    """sums[32k + j] = weight sum over ``rows`` rows of pixel column 32k + j,
    for the ``blocks`` blocks of _AVX2_BLOCK pixels of the rows starting at
    flat[start], flat[start + row_bytes], ... (96 bytes of each row a block).

    ``table`` as for :func:`_bin_column_sums`.  A channel's 32 weights, as
    bytes, are four byte planes of two 16-byte halves each: a 32-entry table
    of floats that vpshufb (16 entries per 128-bit lane) can look up.  Per
    block and row: three 256-bit vectors of the 96 bytes (pixels 0-15 in the
    low lanes, 16-31 in the high ones), shifted to ``value >> 3``; per
    channel three vpshufb and two ors pick its byte of each pixel, two adds
    steer the bins 0-15 and 16-31 into the two halves (an index with its top
    bit set gives zero), two vpshufb and an or per byte plane look the
    weights up, and eight unpacks put the four planes' bytes together into
    four vectors of 8 floats (pixels 4k .. 4k + 3 and 16 + 4k .. 19 + 4k).
    Each pixel's weight is ``(w0 + w1) + w2`` and its column's sum adds the
    rows in order, as in the AVX-512 path: the two give the same sums.
    """
    sig = types.void(flat, start, row_bytes, rows, blocks, table, sums)

    def codegen(context, builder, signature, args):
        (flat_a, table_a, sums_a), (start, row_bytes, rows, blocks) = _column_sum_arguments(
            context, builder, signature, args)
        i8, i16, i32, f32 = ir.IntType(8), ir.IntType(16), ir.IntType(32), ir.FloatType()
        v16i8, v32i8 = ir.VectorType(i8, 16), ir.VectorType(i8, 32)
        v16i16, v8f32, v16f32 = ir.VectorType(i16, 16), ir.VectorType(f32, 8), ir.VectorType(f32, 16)
        pshufb = builder.module.declare_intrinsic(
            "llvm.x86.avx2.pshuf.b", fnty=ir.FunctionType(v32i8, [v32i8, v32i8]))

        def const(value):
            return ir.Constant(start.type, value)

        def indices(values):
            return ir.Constant(ir.VectorType(i32, len(values)), values)

        def byte_splat(value):
            return ir.Constant(v32i8, _i8([value] * 32))

        # planes[c][half][k]: byte k of weights 16 * half .. 16 * half + 15 of
        # channel c, in both lanes.
        v16i32 = ir.VectorType(i32, 16)
        planes = []
        for c in range(3):
            halves = []
            for half in range(2):
                words = builder.bitcast(load_vector(builder, table_a.data,
                                                    const(_BINS * c + 16 * half), v16f32, align=4),
                                        v16i32)
                halves.append([builder.shuffle_vector(
                    *([builder.trunc(builder.lshr(words, ir.Constant(v16i32, [8 * k] * 16)),
                                     v16i8)] * 2), indices(list(range(16)) * 2))
                    for k in range(4)])
            planes.append(halves)
        masks = [[ir.Constant(v32i8, mask) for mask in row] for row in _deinterleave_masks()]
        low_bins, high_bins = byte_splat(0x70), byte_splat(0xF0)
        unpack8 = [indices(_lane_interleave(32, half)) for half in range(2)]
        unpack16 = [indices(_lane_interleave(16, half)) for half in range(2)]
        accumulators = [cgutils.alloca_once(builder, v8f32) for _ in range(4)]
        zero = ir.Constant(v8f32, [0.0] * 8)
        with cgutils.for_range(builder, blocks) as block:
            top = builder.add(start, builder.mul(block.index, const(3 * _AVX2_BLOCK)))
            for accumulator in accumulators:
                builder.store(zero, accumulator)
            with cgutils.for_range(builder, rows) as row:
                at = builder.add(top, builder.mul(row.index, row_bytes))
                sources = []
                for s in range(3):
                    pair = [load_vector(builder, flat_a.data,
                                        builder.add(at, const(16 * s + 48 * lane)), v16i8)
                            for lane in range(2)]
                    both = builder.shuffle_vector(pair[0], pair[1], indices(list(range(32))))
                    shifted = builder.lshr(builder.bitcast(both, v16i16),
                                           ir.Constant(v16i16, [_BIN_SHIFT] * 16))
                    sources.append(builder.and_(builder.bitcast(shifted, v32i8), byte_splat(31)))
                weights = None
                for c in range(3):
                    picked = [builder.call(pshufb, [sources[s], masks[c][s]]) for s in range(3)]
                    bins = builder.or_(builder.or_(picked[0], picked[1]), picked[2])
                    low, high = builder.add(bins, low_bins), builder.add(bins, high_bins)
                    plane = [builder.or_(builder.call(pshufb, [planes[c][0][k], low]),
                                         builder.call(pshufb, [planes[c][1][k], high]))
                             for k in range(4)]
                    pairs = [builder.bitcast(builder.shuffle_vector(plane[2 * p], plane[2 * p + 1],
                                                                    unpack8[half]), v16i16)
                             for half in range(2) for p in range(2)]
                    looked_up = [builder.bitcast(builder.shuffle_vector(pairs[2 * half],
                                                                        pairs[2 * half + 1],
                                                                        unpack16[quarter]), v8f32)
                                 for half in range(2) for quarter in range(2)]
                    weights = looked_up if weights is None else [
                        builder.fadd(w, v) for w, v in zip(weights, looked_up)]
                for accumulator, weight in zip(accumulators, weights):
                    builder.store(builder.fadd(builder.load(accumulator), weight), accumulator)
            sums_at = [builder.load(accumulator) for accumulator in accumulators]
            # Accumulator k holds pixels 4k .. 4k + 3 and 16 + 4k .. 19 + 4k.
            for part, (first, lane) in enumerate([(0, 0), (2, 0), (0, 1), (2, 1)]):
                picked = builder.shuffle_vector(
                    sums_at[first], sums_at[first + 1],
                    indices([4 * lane + j for j in range(4)] + [8 + 4 * lane + j for j in range(4)]))
                store_vector(builder, picked, sums_a.data,
                             builder.add(builder.mul(block.index, const(_AVX2_BLOCK)),
                                         const(8 * part)), align=4)
        return context.get_dummy_value()

    return sig, codegen


@njit(cache=True, nogil=True, inline="always")
def _tile_row_bins_avx2(flat, row_bytes, lut, table, tile, y0, columns, out):
    """:func:`_tile_row_bins` with AVX2 blocks of 32 pixels (their reads stay
    inside their own pixels, so every whole block of the tile row is one)."""
    t = uint64(tile)
    row = uint64(row_bytes)
    start = uint64(y0) * row
    blocks = uint64(out.size) * t // uint64(_AVX2_BLOCK)
    _bin_column_sums_avx2(flat, start, row, t, blocks, table, columns)
    _finish_tile_row(flat, row, lut, t, start, blocks * uint64(_AVX2_BLOCK), columns, out)


# -- box mean ----------------------------------------------------------------
@njit(cache=True, nogil=True, **CALLED_FROM_KERNELS_ONLY)
def _box_pixels(flat, row_bytes, factor, scale, box_flat, box_w, oy, ox0):
    """Output pixels [ox0, box_w) of output row oy, one at a time."""
    f = uint64(factor)
    row = uint64(row_bytes)
    for ox in range(uint64(ox0), uint64(box_w)):
        base = uint64(oy) * f * row + ox * f * _C
        t0 = np.int32(0)
        t1 = np.int32(0)
        t2 = np.int32(0)
        for dy in range(f):
            for dx in range(f):
                i = base + dy * row + dx * _C
                t0 += np.int32(flat[i])
                t1 += np.int32(flat[i + uint64(1)])
                t2 += np.int32(flat[i + uint64(2)])
        o = (uint64(oy) * uint64(box_w) + ox) * _C
        box_flat[o] = np.float32(t0) * scale
        box_flat[o + uint64(1)] = np.float32(t1) * scale
        box_flat[o + uint64(2)] = np.float32(t2) * scale


@njit(cache=True, nogil=True, **CALLED_FROM_KERNELS_ONLY)
def _box_rows(flat, row_bytes, factor, box_flat, box_w, oy0, oy1):
    """Output rows [oy0, oy1) of the box mean: whole blocks of _BOX_BLOCK
    pixels for factors 1, 2 and 4, the rest one pixel at a time."""
    scale = np.float32(1.0 / (factor * factor))
    blocks = box_w // _BOX_BLOCK if factor == 1 or factor == 2 or factor == 4 else 0
    row = uint64(row_bytes)
    step = uint64(3 * factor * _BOX_BLOCK)
    for oy in range(oy0, oy1):
        top = uint64(oy) * uint64(factor) * row
        out = uint64(oy) * uint64(box_w) * _C
        for k in range(uint64(blocks)):
            if factor == 2:
                _box2_block(flat, top + k * step, row, box_flat, out + k * uint64(3 * _BOX_BLOCK))
            elif factor == 1:
                _box1_block(flat, top + k * step, row, box_flat, out + k * uint64(3 * _BOX_BLOCK))
            else:
                _box4_block(flat, top + k * step, row, box_flat, out + k * uint64(3 * _BOX_BLOCK))
        _box_pixels(flat, row_bytes, factor, scale, box_flat, box_w, oy, blocks * _BOX_BLOCK)


@njit(cache=True, nogil=True, **CALLED_FROM_KERNELS_ONLY)
def _scalar_tile_row(flat, row_bytes, lut, tile, y0, columns, out):
    """One tile row's sums by per-pixel lookups, for any lut: the vector paths'
    order (:func:`_finish_tile_row` from the first column), so for a lut with
    a bin table every CPU gives the same sums."""
    row = uint64(row_bytes)
    _finish_tile_row(flat, row, lut, uint64(tile), uint64(y0) * row, uint64(0), columns, out)


# -- driver --------------------------------------------------------------------
#: The bin-table path the CPU Numba compiles for has, as
#: :mod:`fastdet.kernels._llvm` finds its features (honouring NUMBA_CPU_NAME /
#: NUMBA_CPU_FEATURES): AVX-512F and BW (512-bit vpshufb and vpermi2ps), else
#: AVX2, else none.  _CAN_AVX512BW and _CAN_AVX2, fixed at import, are
#: compile-time constants of _colour_maps, so each target compiles only its
#: own vector branch (Numba keys its cache by the target CPU).
_CAN_AVX512BW = HAVE_AVX512BW
_CAN_AVX2 = HAVE_AVX2 and not HAVE_AVX512BW

#: The best tile-sum path this CPU has: the only one _colour_maps compiles
#: for a ``path`` of None.
NATIVE_TILE_PATH = PATH_AVX512 if _CAN_AVX512BW else PATH_AVX2 if _CAN_AVX2 else PATH_SCALAR

#: The tile-sum path colour_maps asks for (tests set it to PATH_SCALAR too).
TILE_PATH = NATIVE_TILE_PATH


@njit(cache=True, nogil=True, inline="always")
def _native_tile_row(flat, row_bytes, lut, table, tile, y0, columns, out):
    """One tile row's sums on this CPU's best path (:data:`NATIVE_TILE_PATH`)."""
    if _CAN_AVX512BW:
        _tile_row_bins(flat, row_bytes, lut, table, tile, y0, columns, out)
    elif _CAN_AVX2:
        _tile_row_bins_avx2(flat, row_bytes, lut, table, tile, y0, columns, out)
    else:
        _scalar_tile_row(flat, row_bytes, lut, tile, y0, columns, out)


@njit(cache=True, nogil=True, inline="always")
def _tile_row_on_path(path, flat, row_bytes, lut, table, tile, y0, columns, out):
    """One tile row's sums on ``path`` if this CPU has it, else by lookups;
    returns the path taken."""
    if path == PATH_AVX512:
        if _CAN_AVX512BW:
            _tile_row_bins(flat, row_bytes, lut, table, tile, y0, columns, out)
            return PATH_AVX512
    elif path == PATH_AVX2:
        if _CAN_AVX2:
            _tile_row_bins_avx2(flat, row_bytes, lut, table, tile, y0, columns, out)
            return PATH_AVX2
    _scalar_tile_row(flat, row_bytes, lut, tile, y0, columns, out)
    return PATH_SCALAR


@njit(cache=True, nogil=True)
def _colour_maps(path, image, lut, table, tile, factor, want_tiles, want_box, tiles, box):
    """Fill ``tiles`` and ``box``; return the tile-sum path taken: ``path``
    (PATH_AVX512, PATH_AVX2 or PATH_SCALAR), or PATH_SCALAR without tiles to
    sum or where the CPU lacks that path's instructions.  A vector path needs
    ``table``, the lut's :func:`bin_table`: the caller has checked it has one.

    ``path`` None is :data:`NATIVE_TILE_PATH`, and then the only path
    compiled: Numba drops the branches of a ``None`` argument before typing,
    so the detector's calls compile no per-pixel lookup loops where the CPU
    has a vector path (about 0.75 s of the family's first compile).  An
    integer ``path`` is chosen at run time among all
    the paths the CPU has (the tests, a lut without a bin table).
    """
    width = image.shape[1]
    row_bytes = width * 3
    flat = flat_view(image)
    lut_flat = flat_view(lut)
    box_h, box_w = box.shape[0], box.shape[1]
    box_flat = flat_view(box)
    columns = empty(width if want_tiles else 0, np.float32)
    taken = PATH_SCALAR
    # Box rows written so far; an int64 from the start, not the literal 0,
    # so that _box_rows is compiled once.
    done = np.int64(0)
    for ty in range(tiles.shape[0] if want_tiles else 0):
        if path is None:
            _native_tile_row(flat, row_bytes, lut_flat, table, tile, ty * tile, columns,
                             tiles[ty])
            taken = NATIVE_TILE_PATH
        else:
            taken = _tile_row_on_path(path, flat, row_bytes, lut_flat, table, tile, ty * tile,
                                      columns, tiles[ty])
        if want_box:
            # The box rows whose source rows this tile row has just read.
            ready = min(box_h, (ty + 1) * tile // factor)
            if ready > done:
                _box_rows(flat, row_bytes, factor, box_flat, box_w, done, ready)
                done = ready
    if want_box and box_h > done:
        _box_rows(flat, row_bytes, factor, box_flat, box_w, done, box_h)
    return taken


def colour_maps(image, lut=None, tile=8, factor=0, out=(None, None)):
    """Histogram-weight tile sums and the box-averaged image, in one pass.

    Parameters
    ----------
    image : ndarray of uint8, shape (H, W, 3)
        Colour-converted image (C-contiguous).
    lut : ndarray of float32, shape (3, 256), optional
        Weight of each channel value; ``None`` skips the tile sums.
    tile : int
        Tile side of the sums.
    factor : int
        Box-averaging factor of the spatial image; 0 skips it.
    out : tuple of ndarray or None
        C-contiguous float32 arrays of the results' shapes to write the tile
        sums and the box means into (``None``: new arrays).

    Returns
    -------
    tiles : ndarray of float32, shape (H // tile, W // tile) or (0, 0)
        Sum over each tile of ``sum_c lut[c, image[y, x, c]]``.
    box : ndarray of float32, shape (H // factor, W // factor, 3) or (0, 0, 3)
        Mean of every ``factor x factor`` tile of ``image``.

    Notes
    -----
    Tile sums are faster where each channel of ``lut`` is constant on aligned
    runs of 8 values (``lut[c, v] == lut[c, v & ~7]``), as the detector's lut
    is for 32 histogram bins or fewer, and Numba compiles for a CPU with
    AVX-512BW (about four times) or AVX2 (about 1.6 times).  Every path adds
    in one order (float32 sums), so for such a lut all CPUs give the same
    sums.
    """
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise ValueError(f"expected a uint8 (H, W, 3) image, got {image.dtype} {image.shape}")
    # Every element is written by the kernel: new arrays need no zeroing.
    rows = ColourMapRows(image.shape, lut, tile, factor, out)
    rows(np.ascontiguousarray(image), 0, image.shape[0])
    return rows.tiles, rows.box


class ColourMapRows:
    """:func:`colour_maps` of uint8 images of one shape into one pair of arrays,
    checked and sized once; each call computes the maps of some pixel rows.

    For the detector's scales (see :class:`~fastdet.kernels.score.WindowRowScorer`).

    Parameters
    ----------
    image_shape : tuple of int
        ``(H, W, 3)`` of the images the calls take.
    lut, tile, factor
        As :func:`colour_maps` takes them.
    out : tuple of ndarray
        ``(tiles, box)``: C-contiguous float32 arrays of the shapes
        :func:`colour_maps` returns for a whole image.
    """

    def __init__(self, image_shape, lut, tile, factor, out):
        height, width, channels = (int(n) for n in image_shape)
        if channels != 3:
            raise ValueError(f"expected (H, W, 3) images, got shape {tuple(image_shape)}")
        if lut is not None and np.shape(lut) != (3, 256):
            raise ValueError(f"lut must have shape (3, 256), got {np.shape(lut)}")
        tile, factor = int(tile), int(factor)
        if tile < 1 or factor < 0:
            raise ValueError(f"tile must be >= 1 and factor >= 0, got {tile!r}, {factor!r}")
        self.image_shape = (height, width, 3)
        self.tile, self.factor = tile, factor
        self.tiles = _colour_out(out[0], (height // tile, width // tile) if lut is not None
                                 else (0, 0))
        self.box = _colour_out(out[1], (height // factor, width // factor, 3) if factor
                               else (0, 0, 3))
        self._want = (lut is not None, factor > 0)
        self._lut = (np.zeros((3, 256), np.float32) if lut is None
                     else np.ascontiguousarray(lut, np.float32))
        table = bin_table(self._lut) if lut is not None else None
        self._table = np.zeros(3 * _BINS, np.float32) if table is None else table
        self._path = PATH_SCALAR if table is None else TILE_PATH
        # None: the native path, compiled alone (see _colour_maps).
        if self._path == NATIVE_TILE_PATH:
            self._path = None
        # Rows a call may start or stop at: whole tiles (when there are tile
        # sums) and boxes.
        self._align = int(np.lcm(tile if lut is not None else 1, max(factor, 1)))

    def __call__(self, image, top, bottom):
        """Compute the maps of pixel rows ``top`` .. ``bottom - 1`` of ``image`` (both
        multiples of the box factor, and of the tile when there are tile sums) into
        :attr:`tiles` and :attr:`box`."""
        arguments = self.arguments(image, top, bottom)
        if arguments is not None:
            _colour_maps(*arguments)

    def arguments(self, image, top, bottom):
        """The arguments of the ``_colour_maps`` kernel call :meth:`__call__` makes,
        or None when it computes nothing."""
        if (image.shape != self.image_shape or image.dtype != np.uint8
                or not image.flags.c_contiguous):
            raise ValueError(f"expected a C-contiguous uint8 image of shape {self.image_shape}, "
                             f"got {image.dtype} {image.shape}")
        if top % self._align or (bottom % self._align and bottom < self.image_shape[0]):
            raise ValueError(f"rows {top}..{bottom} cut tiles of {self.tile} or boxes of "
                             f"{self.factor} pixels")
        top, bottom = max(0, int(top)), min(self.image_shape[0], int(bottom))
        if top >= bottom:
            return None
        tile, factor = self.tile, max(self.factor, 1)
        tiles = self.tiles[top // tile:bottom // tile] if self._want[0] else self.tiles
        box = self.box[top // factor:bottom // factor] if self._want[1] else self.box
        return (self._path, image[top:bottom], self._lut, self._table, tile, self.factor,
                self._want[0], self._want[1], tiles, box)


def _colour_out(out, shape):
    if out is None:
        return np.empty(shape, np.float32)
    if out.shape != shape or out.dtype != np.float32 or not out.flags.c_contiguous:
        raise ValueError(f"out arrays must be C-contiguous float32 of shape {shape}, "
                         f"got {out.dtype} {out.shape}")
    return out
