"""Per-pixel colour kernel: tile sums of colour-histogram weights.

The colour histogram's share of a window's score is linear in the per-pixel
bin indicators, so it equals the window sum of a per-pixel weight
``sum_c lut[c, value_c]``.  Windows are made of whole tiles (the tile side
divides both the window side and the window step), so per-tile sums are all a
frame needs; :func:`fastdet.kernels.score.add_tile_window_sums` adds them up
per window.
"""

import numpy as np
from numba import njit, uint64

# Reassociation lets LLVM vectorise the per-tile reductions.
_FASTMATH = {"reassoc", "nsz", "contract"}


@njit(cache=True, fastmath=_FASTMATH)
def tile_weight_sums(image, lut, tile):
    """Sum of ``sum_c lut[c, image[y, x, c]]`` over every ``tile x tile`` tile.

    Parameters
    ----------
    image : ndarray of uint8, shape (H, W, C)
        C-contiguous.
    lut : ndarray of float32, shape (C, 256)
        Weight of each channel value.
    tile : int
        Tile side; pixels beyond the last whole tile are ignored.

    Returns
    -------
    ndarray of float32, shape (H // tile, W // tile)
    """
    height, width, channels = image.shape
    tiles_y, tiles_x = height // tile, width // tile
    out = np.zeros((tiles_y, tiles_x), dtype=np.float32)
    used = uint64(tiles_x * tile)
    c64 = uint64(channels)
    t64 = uint64(tile)
    flat = image.reshape(height, width * channels)
    lut_flat = lut.reshape(lut.size)
    pixel = np.zeros(max(width, 1), dtype=np.float32)
    for y in range(tiles_y * tile):
        src = flat[y]
        for x in range(used):
            pixel[x] = lut_flat[uint64(src[x * c64])]
        for c in range(uint64(1), c64):
            offset = c * uint64(256)
            for x in range(used):
                pixel[x] += lut_flat[offset + uint64(src[x * c64 + c])]
        row = out[y // tile]
        for tx in range(uint64(tiles_x)):
            total = np.float32(0.0)
            for x in range(tx * t64, (tx + uint64(1)) * t64):
                total += pixel[x]
            row[tx] += total
    return out
