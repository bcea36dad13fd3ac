"""The cell stage of HOG for float64 images, computed as scikit-image computes it.

scikit-image turns a float64 image into float64 central-difference gradients
(zero on the outermost rows and columns), keeps per pixel the channel whose
``np.hypot`` magnitude is largest (multichannel images, first channel on
ties), and bins ``np.rad2deg(np.arctan2(gy, gx)) % 180`` into ``[k * 180 /
nbins, (k + 1) * 180 / nbins)``.  Each cell's ``np.hypot`` magnitudes are
summed per bin in a C ``float`` (every partial sum rounded to float32, in
row-major order) and the sum is divided by the cell's pixel count in float32.

The gradients, magnitudes and angles are computed here with the same NumPy
expressions: NumPy's ``arctan2`` may be a SIMD version that differs from the C
library's in the last bit, and that bit decides the bin of a gradient lying
within rounding of a boundary (a blurred circle has hundreds).  They are
computed a band of cell rows at a time, so memory stays bounded on large
images; a Numba kernel bins and sums them in scikit-image's order and
precision, so the cells agree with scikit-image's to the last bit.
"""

import numpy as np
from numba import njit

#: Pixels (rows x width x channels) per band: bounds the float64 temporaries.
_BAND_PIXELS = 1 << 20


@njit(cache=True, nogil=True)
def _sum_band(angle, magnitude, bounds, ppc_y, ppc_x, first_cell_row, sums):
    """Add a band's magnitudes to ``sums[cy, cx, c, bin]`` (float32, as scikit-image sums)."""
    rows, _, channels = angle.shape
    ncx, nbins = sums.shape[1], sums.shape[3]
    width = ncx * ppc_x
    step = 180.0 / nbins
    for r in range(rows):
        cy = first_cell_row + r // ppc_y
        for c in range(channels):
            for x in range(width):
                a = angle[r, x, c]
                if np.isnan(a):
                    # scikit-image skips a pixel when its angle lies outside a
                    # bin: a NaN never does, so it goes into every bin.
                    for b in range(nbins):
                        sums[cy, x // ppc_x, c, b] += magnitude[r, x, c]
                    continue
                if a >= bounds[nbins]:
                    continue  # rounded to 180 degrees: in no bin
                b = min(int(a / step), nbins - 1)
                while a < bounds[b]:
                    b -= 1
                while a >= bounds[b + 1]:
                    b += 1
                # float32 += float64 is computed in float64 and rounded: a C float's +=.
                sums[cy, x // ppc_x, c, b] += magnitude[r, x, c]


def _band_gradients(image, first, stop):
    """float64 ``(gy, gx)`` of image rows ``first`` .. ``stop - 1``, as scikit-image takes them."""
    height = image.shape[0]
    rows = np.arange(first, stop)
    interior = (rows > 0) & (rows < height - 1)
    gy = np.zeros((stop - first,) + image.shape[1:])
    gy[interior] = image[rows[interior] + 1] - image[rows[interior] - 1]
    gx = np.zeros_like(gy)
    gx[:, 1:-1] = image[first:stop, 2:] - image[first:stop, :-2]
    return gy, gx


def _strongest_channel(gy, gx):
    """Per pixel, the gradient of the channel with the largest magnitude (first on ties)."""
    strongest = np.hypot(gy, gx).argmax(axis=2)[:, :, None]
    return (np.take_along_axis(gy, strongest, axis=2), np.take_along_axis(gx, strongest, axis=2))


def float64_cell_histograms(image, ppc_y, ppc_x, nbins, merge_channels, bounds, out):
    """Fill ``out`` (float64, ``(Hc, Wc, C_out, nbins)``) with scikit-image's cells.

    Parameters
    ----------
    image : ndarray of float64, shape (H, W, C)
    ppc_y, ppc_x : int
        Pixels per cell.
    nbins : int
    merge_channels : bool
        scikit-image's multichannel rule (one output channel).
    bounds : ndarray of float64, shape (nbins + 1,)
        Bin boundaries in degrees (:func:`fastdet.kernels.hog.orientation_tables`).
    out : ndarray of float64
    """
    cells_y = out.shape[0]
    sums = np.zeros(out.shape, dtype=np.float32)
    per_cell_row = max(1, ppc_y * image.shape[1] * image.shape[2])
    band = max(1, _BAND_PIXELS // per_cell_row)
    for first in range(0, cells_y, band):
        stop = min(cells_y, first + band)
        gy, gx = _band_gradients(image, first * ppc_y, stop * ppc_y)
        if merge_channels:
            gy, gx = _strongest_channel(gy, gx)
        angle = np.rad2deg(np.arctan2(gy, gx)) % 180
        _sum_band(angle, np.hypot(gx, gy), bounds, ppc_y, ppc_x, first, sums)
    out[...] = sums / np.float32(ppc_y * ppc_x)
    return out
