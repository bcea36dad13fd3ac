"""BGR to HLS conversion of uint8 images, as OpenCV's
``cv2.cvtColor(image, cv2.COLOR_BGR2HLS)``: bit-identical to its AVX2 code at
every width, on every CPU (see *OpenCV's two rules*).

OpenCV's rule for 8-bit images, as reproduced here (all float32 unless noted;
the tests compare every one of the 2**24 colours with OpenCV):

* ``b, g, r = byte * float32(1 / 255)``; ``vmax``, ``vmin`` their max / min;
  ``diff = vmax - vmin``, ``msum = vmax + vmin``, ``l = msum * 0.5``;
* ``s = diff / (msum if l < 0.5 else 2 - msum)``;
* hue: if ``vmax == r``: ``hd = g - b`` and ``hpart = 360 if g < b else 0``;
  elif ``vmax == g``: ``hd = b - r``, ``hpart = 120``; else ``hd = r - g``,
  ``hpart = 240``; ``h = fma(hd, 60 / diff, hpart)`` (one rounding);
* if not ``diff > FLT_EPSILON``: ``h = s = 0``;
* output ``round_half_even(h * 0.5)``, ``round_half_even(l * 255)``,
  ``round_half_even(s * 255)`` saturated to 0..255, channels H, L, S.

Whole runs of 16 pixels are one block of generic LLVM vector IR
(:func:`_hls_block`): the 48 bytes are split into the three channels with
constant shuffles, the arithmetic is done on ``<16 x float>`` (the fused
multiply-add of :func:`fastdet.kernels._llvm.fused_multiply_add`: ``llvm.fma``,
or its exact float64 emulation on CPUs without FMA, where ``llvm.fma`` would
call libm per lane) and the results are interleaved back with shuffles.  No
x86-specific intrinsics, so it is portable; LLVM picks the vector width.  The
fused multiply-add is emulated in the scalar tail loop as
``float32(float64(hd) * float64(inv) + float64(hpart))`` (the product is exact
in float64); the tests check both paths on every colour.

OpenCV's two rules: OpenCV itself is not uniform.  It converts each row in
chunks of 256 pixels with SIMD code for whole runs of its vector width and
scalar code for the rest of a chunk.  Its scalar code, as its AVX2 and
AVX-512 builds compile it, rounds differently: ``s`` divides by
``(2 - vmax) - vmin``; the red branch's hue is the rounded product
``hd * inv`` plus 360 (a second rounding) when negative, while the green and
blue branches' ``hd * inv + 120`` and ``+ 240`` are fused into one FMA by the
compiler.  The vector width depends on the CPU: runs of 8 with its AVX2 code,
of 16 where it runs its AVX-512 code (a 15-pixel row is then scalar all
through).  fastdet follows the AVX2 code's placement on every CPU, so that its
output does not depend on the machine: SIMD rule for whole runs of 8,
``width % 8`` scalar-rule pixels per chunk (none for widths that are
multiples of 8, such as the detector's 960, 1280 and 1920).  The tests check
every colour on both rules against OpenCV itself (``tests/naive.py``'s
``opencv_hls``, which reads each pixel's two values off OpenCV on any CPU).
On CPUs without AVX2, OpenCV runs builds without FMA, which round both kinds
of pixels differently again; every machine fastdet has run on has AVX2.
"""

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

from ._llvm import fused_multiply_add, load_vector, store_vector
from .inner import CALLED_FROM_KERNELS_ONLY
from .prefetch import prefetch_byte

#: Pixels per vector block.
_BLOCK = 16
_BLOCK_BYTES = 3 * _BLOCK
#: OpenCV's row chunk in cvtColor, and the SIMD run of its AVX2 code: the
#: pixels past the last whole run of a chunk take its scalar code.
_CV_CHUNK = 256
_CV_LANES = 8
_FLT_EPSILON = float(np.finfo(np.float32).eps)
_INV255 = float(np.float32(1.0 / 255.0))


#: Adding 1.5 * 2**23 to a float32 in [0, 2**22) rounds it to an integer
#: (half to even, the default rounding mode) held in its low mantissa bits.
_MAGIC = 12582912.0


@intrinsic
def _hls_block(typingctx, src, src_offset, dest, dest_offset):
    """dest[dest_offset:dest_offset + 48] = HLS of the 16 BGR pixels at
    src[src_offset:src_offset + 48] (byte offsets from each array's first
    element; the caller keeps them in bounds)."""
    sig = types.void(src, src_offset, dest, dest_offset)

    def codegen(context, builder, signature, args):
        src_a = context.make_array(signature.args[0])(context, builder, args[0])
        dest_a = context.make_array(signature.args[2])(context, builder, args[2])
        n = _BLOCK
        i8, i32, f32 = ir.IntType(8), ir.IntType(32), ir.FloatType()
        v_i32, v_f32 = ir.VectorType(i32, n), ir.VectorType(f32, n)

        def mask(indices):
            return ir.Constant(ir.VectorType(i32, len(indices)), indices)

        def const(value, vtype=v_f32):
            return ir.Constant(vtype, [value] * n)

        # Pixel k as the 32-bit word b | g << 8 | r << 16: four 16-byte loads
        # (pixels 0-3, 4-7, 8-11 at their start, 12-15 at the end of the
        # last one, which stays within the 48 bytes) joined into 64 bytes,
        # then one byte shuffle within each 16-byte lane.
        chunk = ir.VectorType(i8, 16)
        loads = []
        for start in (0, 12, 24, 32):
            offset = builder.add(args[1], ir.Constant(args[1].type, start))
            loads.append(load_vector(builder, src_a.data, offset, chunk))
        low = builder.shuffle_vector(loads[0], loads[1], mask(list(range(32))))
        high = builder.shuffle_vector(loads[2], loads[3], mask(list(range(32))))
        joined = builder.shuffle_vector(low, high, mask(list(range(64))))
        zero = ir.Constant(joined.type, [0] * 64)
        picks = []
        for k in range(4 * n):
            lane, pixel, c = k // 16, (k % 16) // 4, k % 4
            skip = 4 if lane == 3 else 0
            picks.append(16 * lane + skip + 3 * pixel + c if c < 3 else 64)
        words = builder.bitcast(builder.shuffle_vector(joined, zero, mask(picks)), v_i32)
        byte = const(255, v_i32)
        channels = (builder.and_(words, byte),
                    builder.and_(builder.lshr(words, const(8, v_i32)), byte),
                    builder.lshr(words, const(16, v_i32)))
        inv255 = const(_INV255)
        b, g, r = (builder.fmul(builder.sitofp(v, v_f32), inv255) for v in channels)

        def vmax(x, y):
            return builder.select(builder.fcmp_ordered(">", x, y), x, y)

        def vmin(x, y):
            return builder.select(builder.fcmp_ordered("<", x, y), x, y)

        # max(max(r, g), b) exactly as written in the rule (no NaNs here).
        hi = vmax(vmax(r, g), b)
        lo = vmin(vmin(r, g), b)
        diff = builder.fsub(hi, lo)
        msum = builder.fadd(hi, lo)
        light = builder.fmul(msum, const(0.5))
        den = builder.select(builder.fcmp_ordered("<", light, const(0.5)), msum,
                             builder.fsub(const(2.0), msum))
        sat = builder.fdiv(diff, den)
        is_r = builder.fcmp_ordered("==", hi, r)
        is_g = builder.fcmp_ordered("==", hi, g)
        hd = builder.select(is_r, builder.fsub(g, b),
                            builder.select(is_g, builder.fsub(b, r), builder.fsub(r, g)))
        hpart = builder.select(
            is_r, builder.select(builder.fcmp_ordered("<", g, b), const(360.0), const(0.0)),
            builder.select(is_g, const(120.0), const(240.0)))
        inv = builder.fdiv(const(60.0), diff)
        hue = fused_multiply_add(builder, hd, inv, hpart)
        # not (diff > eps): unordered-or-less-equal.
        grey = builder.fcmp_unordered("<=", diff, const(_FLT_EPSILON))
        hue = builder.select(grey, const(0.0), hue)
        sat = builder.select(grey, const(0.0), sat)

        # Round half to even: h * 0.5 is exact, so a multiply and an add round
        # as one fma would; l * 255 and
        # s * 255 are rounded to float32 first, as in the rule.  All three
        # lie in 0..255 for every colour (the tests check all of them), so
        # OpenCV's saturation never acts and is left out.
        magic = const(_MAGIC)
        h32 = builder.bitcast(builder.fadd(builder.fmul(hue, const(0.5)), magic), v_i32)
        l32 = builder.bitcast(builder.fadd(builder.fmul(light, const(255.0)), magic), v_i32)
        s32 = builder.bitcast(builder.fadd(builder.fmul(sat, const(255.0)), magic), v_i32)
        # Word k = h | l << 8 | s << 16 (garbage above), then drop byte 3 of each.
        packed = builder.or_(
            builder.and_(h32, byte),
            builder.or_(builder.shl(builder.and_(l32, byte), const(8, v_i32)),
                        builder.shl(s32, const(16, v_i32))))
        packed = builder.bitcast(packed, ir.VectorType(i8, 4 * n))
        out = builder.shuffle_vector(
            packed, ir.Constant(packed.type, ir.Undefined),
            mask([4 * (k // 3) + k % 3 for k in range(3 * n)]))
        store_vector(builder, out, dest_a.data, args[3])
        return context.get_dummy_value()

    return sig, codegen


#: Rows ahead of the one being converted whose bytes are asked for (see
#: :mod:`fastdet.kernels.prefetch`).
_PREFETCH_ROWS = 2


@njit(cache=True, nogil=True)
def _bgr_to_hls(image, out):
    """``out`` (C-contiguous) = HLS of the whole 16-pixel blocks of every row of
    ``image``, whose rows are runs of 3-byte pixels (pixel stride 3, channel
    stride 1; any row stride).  The pixels past the last whole block are
    :func:`_hls_pixels`' (its own kernel: compiled only for widths that have
    them, not the default search's 960, 1280 or 1920 pixels)."""
    height, width = image.shape[0], image.shape[1]
    src_row = np.int64(image.strides[0])
    dst_row = np.int64(width) * 3
    blocks = width // _BLOCK
    for y in range(height):
        s0 = np.int64(y) * src_row
        d0 = np.int64(y) * dst_row
        # Spread over the row: a burst of a whole row's prefetches at its
        # start left the conversion a third slower than from cache.
        ahead = np.int64(min(y + _PREFETCH_ROWS, height - 1)) * src_row
        for k in range(blocks):
            prefetch_byte(image, ahead + k * _BLOCK_BYTES)
            _hls_block(image, s0 + k * _BLOCK_BYTES, out, d0 + k * _BLOCK_BYTES)


@njit(cache=True, nogil=True)
def _hls_pixels(image, out, first, lanes):
    """``out[:, first:]`` = HLS of ``image[:, first:]`` one pixel at a time, each
    by the rule of the OpenCV code that converts it when OpenCV's SIMD runs
    are ``lanes`` pixels long (``lanes`` 1: every pixel by the SIMD rule;
    more than 256: every pixel by the scalar rule)."""
    height, width = image.shape[0], image.shape[1]
    for y in range(height):
        row = image[y]
        dest = out[y]
        for x in range(first, width):
            # OpenCV converts each row in chunks of _CV_CHUNK pixels, SIMD
            # for whole runs of `lanes` and its scalar code for the rest.
            start = (x // _CV_CHUNK) * _CV_CHUNK
            simd = x - start < (min(_CV_CHUNK, width - start) // lanes) * lanes
            _hls_scalar(row, dest, x, simd)


@njit(cache=True, error_model="numpy", **CALLED_FROM_KERNELS_ONLY)
def _hls_scalar(row, dest, x, simd):
    """HLS of pixel x of one row (2-D views, shape (W, 3))."""
    inv255 = np.float32(_INV255)
    b = np.float32(row[x, 0]) * inv255
    g = np.float32(row[x, 1]) * inv255
    r = np.float32(row[x, 2]) * inv255
    vmax = max(max(r, g), b)
    vmin = min(min(r, g), b)
    diff = vmax - vmin
    msum = vmax + vmin
    l = msum * np.float32(0.5)
    den = msum if l < np.float32(0.5) else np.float32(2.0) - msum
    h = np.float32(0.0)
    s = np.float32(0.0)
    if diff > np.float32(_FLT_EPSILON):
        s = diff / den
        if vmax == r:
            hd = g - b
            hpart = np.float32(360.0) if g < b else np.float32(0.0)
        elif vmax == g:
            hd = b - r
            hpart = np.float32(120.0)
        else:
            hd = r - g
            hpart = np.float32(240.0)
        inv = np.float32(60.0) / diff
        if simd:
            # The float64 product of two float32 is exact, so this is one
            # rounding to float64, then to float32: the tests check it equals
            # OpenCV (and the fused multiply-add of the vector path) on every
            # colour.
            h = np.float32(np.float64(hd) * np.float64(inv) + np.float64(hpart))
        else:
            # OpenCV's scalar code as its AVX2 build compiles it (the compiler
            # fuses `hd * inv + 120` and `+ 240` into one FMA, but not the
            # red branch's product, which the `h < 0` test also reads):
            # matched on every colour by test_all_colours_tail_path.
            if not l < np.float32(0.5):
                s = diff / ((np.float32(2.0) - vmax) - vmin)
            if vmax == r:
                h = hd * inv
            else:
                h = np.float32(np.float64(hd) * np.float64(inv) + np.float64(hpart))
            if h < np.float32(0.0):
                h += np.float32(360.0)
    dest[x, 0] = np.uint8(min(max(np.rint(h * np.float32(0.5)), np.float32(0)),
                              np.float32(255)))
    dest[x, 1] = np.uint8(min(max(np.rint(l * np.float32(255.0)), np.float32(0)),
                              np.float32(255)))
    dest[x, 2] = np.uint8(min(max(np.rint(s * np.float32(255.0)), np.float32(0)),
                              np.float32(255)))


def _check(image, out):
    if not isinstance(image, np.ndarray) or image.dtype != np.uint8 or image.ndim != 3 \
            or image.shape[2] != 3:
        raise ValueError(f"expected a uint8 (H, W, 3) image, got "
                         f"{getattr(image, 'dtype', type(image))} {getattr(image, 'shape', '')}")
    if image.strides[2] != 1 or image.strides[1] != 3:
        image = np.ascontiguousarray(image)
    if out is None:
        out = np.empty(image.shape, np.uint8)
    elif (not isinstance(out, np.ndarray) or out.dtype != np.uint8 or out.shape != image.shape
          or not out.flags.c_contiguous or not out.flags.writeable):
        raise ValueError(f"out must be a writeable C-contiguous uint8 array of shape "
                         f"{image.shape}, got {getattr(out, 'dtype', type(out))} "
                         f"{getattr(out, 'shape', '')}")
    return image, out


def bgr_to_hls(image, out=None):
    """``cv2.cvtColor(image, cv2.COLOR_BGR2HLS)`` for uint8 images.

    Bit-identical to OpenCV's AVX2 code at every width, the pixels it
    converts with its scalar code included, on every CPU (see the module
    notes: on CPUs with AVX-512, OpenCV's own output differs from it past
    the last whole 16 pixels of a 256-pixel chunk).

    Parameters
    ----------
    image : ndarray of uint8, shape (H, W, 3)
        BGR image; rows may be strided (e.g. column slices), otherwise it is
        copied first.
    out : ndarray of uint8, shape (H, W, 3), optional
        C-contiguous destination, returned.

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)
        Hue (0..180, degrees / 2), lightness and saturation (0..255).
    """
    image, out = _check(image, out)
    if image.size:
        blocked = image.shape[1] // _BLOCK * _BLOCK
        if blocked:
            _bgr_to_hls(image, out)
        if blocked < image.shape[1]:
            _hls_pixels(image, out, blocked, _CV_LANES)
    return out


def _bgr_to_hls_scalar(image, out=None, lanes=1):
    """As :func:`bgr_to_hls`, every pixel by the one-pixel loop: by default
    with OpenCV's SIMD rule for each (for tests; see :func:`_hls_pixels`)."""
    image, out = _check(image, out)
    if image.size:
        _hls_pixels(image, out, 0, lanes)
    return out
