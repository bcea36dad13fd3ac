"""Reductions over float maps that numpy only does with a temporary mask."""

from __future__ import annotations

import numba
import numpy as np

from .alloc import full

__all__ = ["smallest_positive"]

#: Independent running minima: LLVM vectorises a fixed block of lanes, not one
#: running minimum (whose order of comparisons it must keep).
_LANES = 16


@numba.njit(cache=True, nogil=True, fastmath={"nnan", "nsz", "reassoc"})
def smallest_positive(values):
    """The smallest value above zero in a float32 map, ``inf`` when there is none.

    ``values[values > 0].min()`` without the mask and the copy: one pass over
    the map, about 0.3 ms for a heat map of a 1280x720 frame where numpy's
    masked minimum takes several milliseconds.  NaN is not supported.

    Parameters
    ----------
    values : ndarray of float32, shape (H, W)

    Returns
    -------
    numpy.float32
    """
    inf = np.float32(np.inf)
    lanes = full(_LANES, inf, np.float32)
    height, width = values.shape
    blocked = width // _LANES * _LANES
    smallest = inf
    for y in range(height):
        row = values[y]
        for x in range(0, blocked, _LANES):
            for k in range(_LANES):
                value = row[x + k]
                lanes[k] = min(lanes[k], value if value > 0 else inf)
        for x in range(blocked, width):
            value = row[x]
            if 0 < value < smallest:
                smallest = value
    for k in range(_LANES):
        smallest = min(smallest, lanes[k])
    return smallest
