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

One pass over the colour image produces both.  Colour images always have
three channels here, which the loops hard-code so LLVM can unroll them;
indices are unsigned because Numba's negative-index wraparound would
otherwise keep LLVM from vectorising the row loops.
"""

import numpy as np
from numba import njit, uint64

# Reassociation lets LLVM vectorise the per-tile reductions.
_FASTMATH = {"reassoc", "nsz", "contract"}

_C = uint64(3)


@njit(cache=True)
def _lut_row(src, lut_flat, weight):
    """weight[x] = sum over channels of the LUT entry of pixel x's value."""
    for x in range(uint64(weight.size)):
        weight[x] = (lut_flat[uint64(src[x * _C])]
                     + lut_flat[uint64(256) + uint64(src[x * _C + uint64(1)])]
                     + lut_flat[uint64(512) + uint64(src[x * _C + uint64(2)])])


@njit(cache=True, fastmath=_FASTMATH)
def _add_tile_sums(weight, tile, row):
    """row[tx] += sum of weight over tile tx."""
    t64 = uint64(tile)
    for tx in range(uint64(row.size)):
        total = np.float32(0.0)
        for x in range(tx * t64, (tx + uint64(1)) * t64):
            total += weight[x]
        row[tx] += total


@njit(cache=True)
def _add_row(src, column_sum):
    """column_sum += src (as float32), element by element."""
    for k in range(uint64(column_sum.size)):
        column_sum[k] += np.float32(src[k])


@njit(cache=True, fastmath=_FASTMATH)
def _box_row(column_sum, factor, scale, dest):
    """dest[ox, c] = scale * sum over dx of column_sum[ox * factor + dx, c]."""
    f64 = uint64(factor)
    for ox in range(uint64(dest.size // 3)):
        for c in range(_C):
            total = np.float32(0.0)
            for dx in range(f64):
                total += column_sum[(ox * f64 + dx) * _C + c]
            dest[ox * _C + c] = total * scale


@njit(cache=True)
def _colour_maps(image, lut, tile, factor, want_tiles, want_box, tiles, box):
    # Each row pass is its own small function: LLVM vectorises the short,
    # alias-free loops that one big loop body kept it from vectorising.
    height, width = image.shape[0], image.shape[1]
    flat = image.reshape(height, width * 3)
    lut_flat = lut.reshape(lut.size)
    tiles_x = tiles.shape[1]
    weight = np.zeros(tiles_x * tile, dtype=np.float32)
    box_w = box.shape[1]
    column_sum = np.zeros(box_w * factor * 3, dtype=np.float32)
    scale = np.float32(1.0 / (factor * factor)) if factor > 0 else np.float32(0.0)
    tile_rows = tiles.shape[0] * tile if want_tiles else 0
    box_rows = box.shape[0] * factor if want_box else 0
    for y in range(max(tile_rows, box_rows)):
        src = flat[y]
        if y < tile_rows:
            _lut_row(src, lut_flat, weight)
            _add_tile_sums(weight, tile, tiles[y // tile])
        if y < box_rows:
            _add_row(src, column_sum)
            if (y + 1) % factor == 0:
                _box_row(column_sum, factor, scale, box[y // factor].reshape(box_w * 3))
                column_sum[:] = 0.0


def colour_maps(image, lut=None, tile=8, factor=0):
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

    Returns
    -------
    tiles : ndarray of float32, shape (H // tile, W // tile) or (0, 0)
        Sum over each tile of ``sum_c lut[c, image[y, x, c]]``.
    box : ndarray of float32, shape (H // factor, W // factor, 3) or (0, 0, 3)
        Mean of every ``factor x factor`` tile of ``image``.
    """
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise ValueError(f"expected a uint8 (H, W, 3) image, got {image.dtype} {image.shape}")
    image = np.ascontiguousarray(image)
    height, width = image.shape[:2]
    want_tiles = lut is not None
    want_box = factor > 0
    tiles = np.zeros((height // tile, width // tile) if want_tiles else (0, 0), np.float32)
    box = np.zeros((height // factor, width // factor, 3) if want_box else (0, 0, 3), np.float32)
    lut = np.zeros((3, 256), np.float32) if lut is None else np.ascontiguousarray(lut, np.float32)
    _colour_maps(image, lut, int(tile), int(factor), want_tiles, want_box, tiles, box)
    return tiles, box
