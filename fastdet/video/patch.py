"""What patch tracking looks at: a vehicle's saturation mask, and scene changes.

:class:`PatchModel` finds a vehicle again near its last position by the
overlap of saturation masks; :class:`SceneChangeTrigger` says when a frame
differs enough from the last fully searched one to search it again.
"""

from __future__ import annotations

import numpy as np

from ..kernels.label import label_components
from ..kernels.patch import (
    grey_thumbnail,
    mask_overlap_search,
    saturation_mask,
    sum_squared_difference,
)


class PatchModel:
    """A vehicle's saturation mask, taken from the frame it was detected in.

    The mask is the largest connected region of saturated pixels of the
    detected patch, cropped to its bounding rectangle.  Later frames are
    always compared with this original mask, never with the last tracked
    patch, so a small error in one frame does not carry into the next.

    Parameters
    ----------
    mask : ndarray of uint8, shape (h, w)
        0/1 reference mask.
    origin : tuple of int
        ``(x, y)`` of the mask's top-left corner in the detection frame.
    """

    def __init__(self, mask, origin):
        self.mask = np.ascontiguousarray(mask, dtype=np.uint8)
        self.origin = (int(origin[0]), int(origin[1]))

    @classmethod
    def from_frame(cls, frame, box, threshold, min_pixels):
        """Take the model of the vehicle inside ``box``; ``None`` if it is too faint.

        Parameters
        ----------
        frame : ndarray of uint8, shape (H, W, 3)
        box : array_like of int
            ``[x1, y1, x2, y2]`` of the detection.
        threshold : int
            Saturation threshold.
        min_pixels : int
            Least size of the largest saturated region.
        """
        height, width = frame.shape[:2]
        x1, y1 = max(int(box[0]), 0), max(int(box[1]), 0)
        x2, y2 = min(int(box[2]), width), min(int(box[3]), height)
        if x2 <= x1 or y2 <= y1:
            return None
        mask = saturation_mask(np.ascontiguousarray(frame[y1:y2, x1:x2]), threshold)
        labels, count = label_components(mask, 8)
        if count == 0:
            return None
        sizes = np.bincount(labels.ravel(), minlength=count + 1)
        sizes[0] = 0
        largest = int(np.argmax(sizes))
        if sizes[largest] < min_pixels:
            return None
        rows = np.flatnonzero(np.any(labels == largest, axis=1))
        cols = np.flatnonzero(np.any(labels == largest, axis=0))
        top, bottom, left, right = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
        car = (labels[top:bottom, left:right] == largest).astype(np.uint8)
        return cls(car, (x1 + left, y1 + top))

    def locate(self, frame, position, radius, threshold):
        """Find the mask again near ``position``.

        Parameters
        ----------
        frame : ndarray of uint8, shape (H, W, 3)
        position : tuple of int
            ``(x, y)`` of the mask's top-left corner in the previous frame.
        radius : int
            Largest displacement looked for along each axis.
        threshold : int
            Saturation threshold.

        Returns
        -------
        position : tuple of int or None
            New ``(x, y)``; ``None`` if the mask no longer fits in the frame.
        overlap : float
            IoU of the reference mask with the frame's saturation mask there.
        """
        height, width = frame.shape[:2]
        mask_h, mask_w = self.mask.shape
        x, y = position
        # Only the area reachable within the radius is converted; placements
        # sticking out of the frame are not tried, so a vehicle driving out
        # of the picture loses overlap and is dropped.
        ax1, ay1 = max(x - radius, 0), max(y - radius, 0)
        ax2, ay2 = min(x + mask_w + radius, width), min(y + mask_h + radius, height)
        if ax2 - ax1 < mask_w or ay2 - ay1 < mask_h:
            return None, 0.0
        area = saturation_mask(np.ascontiguousarray(frame[ay1:ay2, ax1:ax2]), threshold)
        coarse = 2 if radius >= 4 else 1
        best_y, best_x, overlap = mask_overlap_search(self.mask, area, (y - ay1, x - ax1),
                                                      radius, coarse)
        if best_y < 0:
            return None, 0.0
        return (ax1 + best_x, ay1 + best_y), overlap


# -- scene change -----------------------------------------------------------------
class SceneChangeTrigger:
    """Says when a frame differs enough from the last fully searched one.

    Frames are compared as grey thumbnails (block means of ``factor x
    factor`` pixels) by their mean squared difference, so the threshold does
    not depend on the frame size.

    Parameters
    ----------
    threshold : float
        Mean squared grey-level difference above which the scene changed.
    factor : int
        Downsampling factor of the thumbnails.
    rows : tuple of int, optional
        ``(y1, y2)`` band of the frame compared (the detector's search
        band); the whole height by default.
    """

    def __init__(self, threshold, factor, rows=None):
        self.threshold = float(threshold)
        self.factor = int(factor)
        self.rows = rows
        self._reference = None
        #: Mean squared difference measured by the last :meth:`changed` call.
        self.last_difference = 0.0

    def thumbnail(self, frame):
        """The grey thumbnail frames are compared by (float32)."""
        band = frame if self.rows is None else frame[self.rows[0]:self.rows[1]]
        return grey_thumbnail(np.ascontiguousarray(band), self.factor)

    def set_reference(self, frame, thumbnail=None):
        """Remember ``frame`` as the last fully searched one.

        ``thumbnail``, if given, is ``self.thumbnail(frame)`` already computed.
        """
        self._reference = self.thumbnail(frame) if thumbnail is None else thumbnail

    def changed(self, frame, thumbnail=None):
        """True when ``frame`` differs from the reference by more than the threshold."""
        if self._reference is None:
            return True
        if thumbnail is None:
            thumbnail = self.thumbnail(frame)
        if thumbnail.shape != self._reference.shape or thumbnail.size == 0:
            return True
        self.last_difference = sum_squared_difference(thumbnail, self._reference) / thumbnail.size
        return self.last_difference > self.threshold
