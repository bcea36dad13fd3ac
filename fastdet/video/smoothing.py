"""Smoothing over frames: heat maps (exponential, FIR, none) and each track's box.

Smoothers take the current heat over a region of the map (the detector
computes it only around its hits) and return the whole smoothed map, so a
false hit in one frame rarely reaches the heat threshold.
"""

from __future__ import annotations

import collections
import math

import numpy as np

from ..kernels.heat import decay_heat


def _placed(heat, offset, shape):
    # The region slice of a map of `shape` that a region heat map covers.
    x, y = offset
    return slice(y, y + heat.shape[0]), slice(x, x + heat.shape[1])


class NoHeatSmoothing:
    """The current heat map, unchanged (``heat_smoothing = "none"``).

    Smoothers take the current heat over a region of the map (the detector
    computes it only around its hits) and return the whole smoothed map.
    """

    def update(self, heat, offset=(0, 0), shape=None):
        """The map to threshold for the current frame.

        Parameters
        ----------
        heat : ndarray of float32, shape (h, w)
            Current heat over a region of the map.
        offset : tuple of int
            ``(x, y)`` of that region in the map.
        shape : tuple of int, optional
            ``(height, width)`` of the map; ``heat.shape`` by default.  The
            region must lie inside it.

        Returns
        -------
        ndarray of float32, shape ``shape``
            Owned by the smoother: read it before the next update.
        """
        full = np.zeros(shape or heat.shape, dtype=np.float32)
        full[_placed(heat, offset, full.shape)] = heat
        return full

    def reset(self):
        """Forget past frames."""


class ExponentialHeat(NoHeatSmoothing):
    """Exponential filter: ``smoothed = (1 - alpha) * smoothed + alpha * current``.

    The first map after a reset is taken as is, so a vehicle present from the
    first frame is found in it rather than after the filter has warmed up.
    Only the decay touches the whole map; the current heat is added over its
    region alone.

    Parameters
    ----------
    alpha : float
        Weight of the current map, in (0, 1].
    """

    def __init__(self, alpha):
        self.alpha = float(alpha)
        self._state = None

    def update(self, heat, offset=(0, 0), shape=None):
        shape = tuple(shape or heat.shape)
        if self._state is None or self._state.shape != shape:
            self._state = super().update(heat, offset, shape)
        else:
            decay_heat(self._state, np.ascontiguousarray(heat, dtype=np.float32),
                       int(offset[0]), int(offset[1]), np.float32(1.0 - self.alpha),
                       np.float32(self.alpha))
        return self._state

    def reset(self):
        self._state = None


class FirHeat(NoHeatSmoothing):
    """Mean of the last ``frames`` heat maps (fewer right after a reset).

    A running sum keeps the cost at two map additions per frame whatever
    ``frames`` is; it is recomputed from the stored maps whenever the ring
    wraps so float rounding cannot accumulate.

    Parameters
    ----------
    frames : int
    """

    def __init__(self, frames):
        self.frames = int(frames)
        self.reset()

    def update(self, heat, offset=(0, 0), shape=None):
        shape = tuple(shape or heat.shape)
        if self._ring is None or self._ring.shape[1:] != shape:
            self._ring = np.zeros((self.frames,) + shape, dtype=np.float32)
            self._sum = np.zeros(shape, dtype=np.float32)
            self._count = self._next = 0
        slot = self._ring[self._next]
        self._sum -= slot
        slot[...] = 0.0
        slot[_placed(heat, offset, shape)] = heat
        self._sum += slot
        self._next = (self._next + 1) % self.frames
        self._count = min(self._count + 1, self.frames)
        if self._next == 0:
            np.sum(self._ring, axis=0, out=self._sum)
        return self._sum / np.float32(self._count)

    def reset(self):
        self._ring = None
        self._sum = None
        self._count = self._next = 0


def make_heat_smoother(config):
    """The heat smoother a :class:`TrackConfig` asks for."""
    if config.heat_smoothing == "exponential":
        return ExponentialHeat(config.heat_alpha)
    if config.heat_smoothing == "fir":
        return FirHeat(config.heat_frames)
    return NoHeatSmoothing()


# -- box smoothing --------------------------------------------------------------
class BoxHistory:
    """The last measured boxes of one vehicle; its box is their corner-wise mean.

    Parameters
    ----------
    frames : int
        How many measurements are averaged.
    """

    def __init__(self, frames):
        self._boxes = collections.deque(maxlen=int(frames))
        self._box = None

    def push(self, box):
        """Add the measurement of a new frame."""
        self._boxes.append(np.asarray(box, dtype=np.int32).copy())
        self._box = None

    def replace_last(self, box):
        """Correct the current frame's measurement."""
        self._boxes[-1] = np.asarray(box, dtype=np.int32).copy()
        self._box = None

    @property
    def box(self):
        """Smoothed ``[x1, y1, x2, y2]`` (int32)."""
        # Frames between detections ask again without new measurements.
        if self._box is None:
            # Python integers for a handful of boxes (np.mean cost 15 us): the
            # integer sums are exact and ``sum / n`` rounds as np.mean does.
            count = len(self._boxes)
            sums = [0, 0, 0, 0]
            for box in self._boxes:
                for k, value in enumerate(box.tolist()):
                    sums[k] += value
            self._box = np.array([math.floor(total / count + 0.5) for total in sums], np.int32)
        return self._box.copy()
