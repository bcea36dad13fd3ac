"""Per-pixel kernels of the video tracker: saturation masks, mask matching, frame change.

Patch tracking follows a vehicle between full detections by the shape of its
saturated pixels: the patch it was first detected in is thresholded on HSV
saturation, and in later frames the position near its last one whose
saturation mask overlaps that reference mask best is taken as the vehicle's.
The scene-change trigger compares small grey thumbnails of two frames.

Algorithms
----------
``saturation_mask`` reproduces OpenCV's 8-bit ``BGR2HSV`` saturation
(``S = round(255 * (max - min) / max)`` in OpenCV's 12-bit fixed point) and
thresholds it in one pass, without materialising H and V.

``mask_overlap_search`` scores candidate offsets of the reference mask
inside a larger candidate mask by intersection over union, counted within
the reference's rectangle (set candidate pixels outside it do not count, so
the background around a vehicle does not penalise the match).  The candidate's
pixel count under each offset comes from its summed-area table (O(1) per
offset).  The intersection uses row bitsets: both masks are packed 64 pixels
to a ``uint64``, each candidate word is realigned to the reference by two
shifts, and set bits of the AND are counted, so an offset costs
O(h * ceil(w / 64)) word operations instead of O(h * w).  The search is
coarse-to-fine: a strided pass over the whole radius, then a dense pass
around its best offset.

``grey_thumbnail`` averages ``factor x factor`` blocks of the channel mean;
``sum_squared_difference`` compares two thumbnails.
"""

from __future__ import annotations

import numba
import numpy as np
from numba import uint64

from .alloc import empty, zeros

__all__ = [
    "grey_thumbnail",
    "mask_overlap_search",
    "saturation_mask",
    "sum_squared_difference",
]

# OpenCV's fixed-point precision for the HSV conversion of 8-bit images.
_HSV_SHIFT = 12


@numba.njit(cache=True, nogil=True)
def saturation_mask(image, threshold):
    """Pixels whose HSV saturation exceeds a threshold.

    Parameters
    ----------
    image : ndarray of uint8, shape (H, W, 3)
        BGR (any channel order gives the same saturation).
    threshold : int
        Saturation level in 0..255; a pixel is set when its saturation, as
        ``cv2.cvtColor(image, cv2.COLOR_BGR2HSV)[..., 1]`` computes it, is
        strictly greater.

    Returns
    -------
    ndarray of uint8, shape (H, W)
        1 where saturated, 0 elsewhere.
    """
    height, width = image.shape[0], image.shape[1]
    # OpenCV's division table: round((255 << 12) / v), 0 for v == 0.
    divide = zeros(256, dtype=np.int64)
    for v in range(1, 256):
        divide[v] = np.int64(np.floor((255 << _HSV_SHIFT) / v + 0.5))
    half = np.int64(1 << (_HSV_SHIFT - 1))
    out = empty((height, width), dtype=np.uint8)
    for y in range(height):
        for x in range(width):
            b = np.int64(image[y, x, 0])
            g = np.int64(image[y, x, 1])
            r = np.int64(image[y, x, 2])
            v = max(b, max(g, r))
            low = min(b, min(g, r))
            s = ((v - low) * divide[v] + half) >> _HSV_SHIFT
            out[y, x] = 1 if s > threshold else 0
    return out


@numba.njit(cache=True, nogil=True, inline="always")
def _popcount(word):
    # Bit-parallel count (Hacker's Delight); LLVM lowers it to POPCNT where available.
    word = word - ((word >> uint64(1)) & uint64(0x5555555555555555))
    word = (word & uint64(0x3333333333333333)) + ((word >> uint64(2)) & uint64(0x3333333333333333))
    word = (word + (word >> uint64(4))) & uint64(0x0F0F0F0F0F0F0F0F)
    return (word * uint64(0x0101010101010101)) >> uint64(56)


@numba.njit(cache=True, nogil=True)
def _pack_rows(mask, words):
    # Row-wise bitsets: bit (x & 63) of word (x >> 6) is pixel x of the row.
    height, width = mask.shape
    packed = zeros((height, words), dtype=np.uint64)
    for y in range(height):
        for x in range(width):
            if mask[y, x]:
                packed[y, x >> 6] |= uint64(1) << uint64(x & 63)
    return packed


@numba.njit(cache=True, nogil=True)
def _summed_area(mask):
    height, width = mask.shape
    table = zeros((height + 1, width + 1), dtype=np.int64)
    for y in range(height):
        row = np.int64(0)
        for x in range(width):
            row += mask[y, x]
            table[y + 1, x + 1] = table[y, x + 1] + row
    return table


@numba.njit(cache=True, nogil=True)
def _intersection(reference_bits, candidate_bits, oy, ox):
    # Set pixels shared by the reference and the candidate window at (oy, ox):
    # each candidate word is realigned to the reference's bit 0 by two shifts.
    height, words = reference_bits.shape
    first = ox >> 6
    right = uint64(ox & 63)
    left = uint64(64) - right
    total = uint64(0)
    for y in range(height):
        ref_row = reference_bits[y]
        cand_row = candidate_bits[oy + y]
        if right == 0:
            for k in range(words):
                total += _popcount(ref_row[k] & cand_row[first + k])
        else:
            for k in range(words):
                shifted = (cand_row[first + k] >> right) | (cand_row[first + k + 1] << left)
                total += _popcount(ref_row[k] & shifted)
    return np.int64(total)


@numba.njit(cache=True, nogil=True)
def _scan(reference_bits, reference_shape, candidate_bits, table, y_span, x_span, step, centre,
          best):
    # Improve best = [iou, y, x, squared distance to centre] over a grid of offsets.
    height, width = reference_shape
    reference_count = best[4]
    for oy in range(y_span[0], y_span[1] + 1, step):
        for ox in range(x_span[0], x_span[1] + 1, step):
            inside = (table[oy + height, ox + width] - table[oy, ox + width]
                      - table[oy + height, ox] + table[oy, ox])
            intersection = _intersection(reference_bits, candidate_bits, oy, ox)
            union = reference_count + inside - intersection
            iou = intersection / union if union > 0 else 0.0
            distance = (oy - centre[0]) ** 2 + (ox - centre[1]) ** 2
            if iou > best[0] or (iou == best[0] and distance < best[3]):
                best[0] = iou
                best[1] = oy
                best[2] = ox
                best[3] = distance


@numba.njit(cache=True, nogil=True)
def mask_overlap_search(reference, candidate, centre, radius, coarse_step):
    """Best placement of a reference mask inside a candidate mask, by IoU.

    Offsets within ``radius`` of ``centre`` are tried every ``coarse_step``
    pixels, then every pixel around the best of those.

    Parameters
    ----------
    reference : ndarray of uint8, shape (h, w)
        0/1 mask being looked for.
    candidate : ndarray of uint8, shape (H, W)
        0/1 mask of the search area; ``H >= h`` and ``W >= w``.
    centre : tuple of int
        ``(y, x)`` top-left offset of the reference inside the candidate
        where the search is centred (the vehicle's last position).  Among
        equally good placements the nearest to it wins, so a uniformly
        saturated area does not make a box wander.
    radius : int
        Largest displacement tried along each axis; offsets are also
        clipped to the placements that fit inside the candidate.
    coarse_step : int
        Stride of the first pass (1 searches densely at once).

    Returns
    -------
    best_y, best_x : int
        Top-left offset of the best placement (``-1, -1`` when the
        reference does not fit in the candidate).
    best_iou : float
        Intersection over union of the reference and the candidate window
        there; 0 when both are empty.
    """
    height, width = reference.shape
    big_h, big_w = candidate.shape
    y_first, y_last = max(centre[0] - radius, 0), min(centre[0] + radius, big_h - height)
    x_first, x_last = max(centre[1] - radius, 0), min(centre[1] + radius, big_w - width)
    if y_first > y_last or x_first > x_last:
        return -1, -1, 0.0
    coarse_step = max(coarse_step, 1)
    words = (width + 63) // 64
    reference_bits = _pack_rows(reference, words)
    # One spare word so realigning the last reference word never reads past a row.
    candidate_bits = _pack_rows(candidate, (big_w + 63) // 64 + 1)
    table = _summed_area(candidate)
    reference_count = 0
    for y in range(height):
        for k in range(words):
            reference_count += _popcount(reference_bits[y, k])
    best = np.array([-1.0, -1.0, -1.0, 0.0, float(reference_count)])
    _scan(reference_bits, (height, width), candidate_bits, table, (y_first, y_last),
          (x_first, x_last), coarse_step, centre, best)
    if coarse_step > 1:
        # The true optimum may sit between coarse offsets: search densely around the best.
        by, bx = int(best[1]), int(best[2])
        reach = coarse_step - 1
        _scan(reference_bits, (height, width), candidate_bits, table,
              (max(by - reach, y_first), min(by + reach, y_last)),
              (max(bx - reach, x_first), min(bx + reach, x_last)), 1, centre, best)
    return int(best[1]), int(best[2]), max(best[0], 0.0)


@numba.njit(cache=True, nogil=True)
def grey_thumbnail(image, factor):
    """Mean of the three channels over every ``factor x factor`` block.

    Parameters
    ----------
    image : ndarray of uint8, shape (H, W, 3)
        C-contiguous.
    factor : int
        Block side, 1 to 256; pixels beyond the last whole block are ignored.

    Returns
    -------
    ndarray of float32, shape (H // factor, W // factor)
        Grey levels in 0..255.
    """
    height, width = image.shape[0], image.shape[1]
    out_h, out_w = height // factor, width // factor
    flat = image.reshape(height, width * 3)
    used = out_w * factor * 3
    # The rows of a block row are first summed element-wise over contiguous
    # memory; uint16 holds up to 256 rows of 255 and keeps the vector
    # lanes narrow, which is what makes this pass fast.
    column_sums = zeros(used, dtype=np.uint16)
    scale = np.float32(1.0 / (3 * factor * factor))
    span = factor * 3
    out = empty((out_h, out_w), dtype=np.float32)
    for by in range(out_h):
        column_sums[:] = 0
        for y in range(by * factor, (by + 1) * factor):
            column_sums += flat[y, :used]
        for bx in range(out_w):
            total = np.uint32(0)
            for x in range(bx * span, (bx + 1) * span):
                total += column_sums[x]
            out[by, bx] = np.float32(total) * scale
    return out


@numba.njit(cache=True, nogil=True)
def sum_squared_difference(a, b):
    """Sum of squared differences of two equally shaped float32 arrays (float64 sum)."""
    flat_a = a.ravel()
    flat_b = b.ravel()
    total = 0.0
    for i in range(flat_a.size):
        d = np.float64(flat_a[i]) - np.float64(flat_b[i])
        total += d * d
    return total
