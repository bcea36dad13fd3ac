"""Software prefetch of image rows a kernel will read next.

The colour conversion reads the search band of a frame the decoder wrote (or,
in ``fastdet bench``, one of 38 frames cycled through): cold in every cache.
Its loop does enough arithmetic per byte that the CPU keeps only a few of the
row's cache misses in flight, and on a 2-core Xeon VM (model 167) the
conversion of a 1280x194 band took 0.46 ms from memory against 0.16 ms from
cache, while a plain copy of the same bytes streamed at 11 GB/s (0.065 ms).
Asking for the row two rows ahead while converting one removes the wait:
0.16 ms from memory.  The resize, reading the converted band after other
scales' work, gains less: a frame's resizes took 0.38 ms from memory and
0.27 ms from cache, 0.31-0.33 ms from memory with its rows asked for ahead.
The side snap of the box refinement reads a short strip of each of a box's
rows from the frame, every row a miss of its own: with all its lines asked
for at once, a frame's labelling stage took 0.121-0.126 against 0.142-0.144
ms.  (The cells, which read what the resize has just written, measured no
change with the next cell row asked for ahead.)

A prefetch is a hint: it never faults and never changes a result, so the
kernels' outputs are the same bytes with and without it.  Numba's on-disk
cache is keyed on the files of the kernels that call these, not on this one:
after changing the lowering, touch those modules.
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

from ._llvm import prefetch
from .inner import CALLED_FROM_KERNELS_ONLY

#: Bytes per cache line on every x86-64 CPU fastdet has met.
LINE_BYTES = 64


@intrinsic
def prefetch_byte(typingctx, array, offset):
    """Hint that byte ``offset`` from ``array``'s first element will be read soon."""
    sig = types.void(array, offset)

    def codegen(context, builder, signature, args):
        data = context.make_array(signature.args[0])(context, builder, args[0]).data
        prefetch(builder, builder.bitcast(data, ir.IntType(8).as_pointer()), args[1])
        return context.get_dummy_value()

    return sig, codegen


@njit(cache=True, nogil=True, **CALLED_FROM_KERNELS_ONLY)
def prefetch_row(image, row):
    """Hint that row ``row`` of ``image`` (its bytes from the row's first
    element, ``image.strides[0]`` apart) will be read soon; rows outside the
    image are not asked for."""
    if row < 0 or row >= image.shape[0]:
        return
    start = np.int64(row) * np.int64(image.strides[0])
    length = np.int64(image.itemsize)
    for extent in image.shape[1:]:
        length *= np.int64(extent)
    for offset in range(start, start + length, LINE_BYTES):
        prefetch_byte(image, offset)
