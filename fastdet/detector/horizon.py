"""The horizon row of a camera, estimated from where the lane lines meet.

The default search is laid out around the horizon (``[search] horizon``, a
fraction of the frame height), and it is sharp about it: on the test video,
searching with the horizon 0.03 of the frame height too high found a third
of the cars, 0.06 too high none (README, "Configuration").  A camera mounted
with another pitch needs its own value; ``[search] horizon = "auto"``
estimates it from the frames.

On a straight road the lane lines are parallel, so in the image they meet at
the road's vanishing point, which lies on the horizon.  Each frame's edges
(:func:`cv2.Canny`) give line segments (:func:`cv2.HoughLinesP`); segments
slanting like lane lines, left ones rising to the right on the left and
right ones on the right, are paired, and the frame's estimate is the
length-weighted median row of the pairs' crossings near their densest row.
The ROI, slopes and bins were set on both videos' lane lines (no vehicle
annotation plays a part).  One frame can be
misled (a car's edge, a curve, a shadow: up to 0.13 of the frame height on
the test video), so a video's horizon is the median over frames, and an
estimate within :data:`DEFAULT_SNAP` of the default searches the default.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .config import DEFAULT_HORIZON
from .frames import check_frame

#: Frames are looked at with this many rows (smaller ones as they are): the
#: crossings need a few pixels of accuracy, not the frame's resolution.
ANALYSIS_ROWS = 360
#: Only crossings in these rows (fractions of the frame height) count: a
#: horizon outside them is no dashcam's.
PLAUSIBLE_ROWS = (0.25, 0.8)
#: Segments are looked for below this row (a fraction of the frame height),
#: where the road is: above it trees, poles and buildings have lane-like
#: slopes too.  The lines' crossing may lie above it.
ROAD_FROM = 0.45
#: Segments this steep (|dy / dx|) can be lane lines: flatter ones are road
#: edges across the view, car roofs and bumpers; steeper ones poles and car sides.
LANE_SLOPES = (0.3, 3.0)
#: Frames smaller than this on a side show no lane lines: they have no horizon.
MIN_SIDE = 16
#: Crossings are grouped into bins of this many frame heights.
BIN = 0.01
#: A video's estimate needs crossings in at least this share of its frames.
MIN_FRAME_SHARE = 0.2
#: Frames of a video looked at: every ``FRAME_STEP``-th of its first
#: ``FRAME_STEP * FRAMES`` (ten seconds at 25 fps).
FRAMES = 25
FRAME_STEP = 10
#: An estimate this close to the built-in horizon (a fraction of the frame
#: height) searches the built-in one: it is within the estimate's error on
#: the two cameras here (0.015), and the detection thresholds and box
#: refinement were tuned there.
DEFAULT_SNAP = 0.02


@dataclass(frozen=True)
class HorizonEstimate:
    """A camera's horizon as estimated from its frames.

    Attributes
    ----------
    fraction : float or None
        The horizon row as a fraction of the frame height from the top;
        ``None`` when too few frames showed lane lines.
    frames : int
        Frames whose lane lines crossed.
    frames_seen : int
        Frames looked at.
    spread : tuple of float or None
        The 10th and 90th percentiles of the frames' own estimates.
    """

    fraction: float | None
    frames: int
    frames_seen: int
    spread: tuple | None = None

    def describe(self):
        """One line for the command line."""
        if self.fraction is None:
            return (f"no horizon found: lane lines crossed in {self.frames} of "
                    f"{self.frames_seen} frames")
        low, high = self.spread
        return (f"horizon at {self.fraction:.3f} of the frame height, from the lane lines "
                f"of {self.frames} of {self.frames_seen} frames (10-90 %: {low:.3f}-{high:.3f})")


def frame_horizon(frame):
    """The row where one frame's lane lines meet, as a fraction of its height.

    Parameters
    ----------
    frame : ndarray of uint8, shape (H, W, 3), (H, W), (H, W, 1) or (H, W, 4)
        BGR, grey or BGRA: the frames a :class:`~fastdet.Detector` takes.

    Returns
    -------
    float or None
        ``None`` when no pair of lane-like segments crosses at a plausible row,
        or the frame is under :data:`MIN_SIDE` pixels on a side (too small to
        show lane lines: a folder of images may hold such a thumbnail).

    Raises
    ------
    InputError
        For a frame a detector refuses too
        (:func:`~fastdet.detector.frames.check_frame`).
    """
    # The detector's own check: (H, W, 1) frames, which detection takes, reached
    # OpenCV's colour conversion and failed there with its message.
    check_frame(frame)
    if min(frame.shape[:2]) < MIN_SIDE:
        return None
    if frame.ndim == 3 and frame.shape[2] == 1:
        frame = frame.reshape(frame.shape[:2])
    # OpenCV's conversion drops a fourth (alpha) channel; a strided grey
    # frame is copied, as the BGR one is by the conversion, for Canny.
    grey = (np.ascontiguousarray(frame) if frame.ndim == 2
            else cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY))
    height, width = grey.shape
    if height > ANALYSIS_ROWS:
        scale = ANALYSIS_ROWS / height
        grey = cv2.resize(grey, (max(1, round(width * scale)), ANALYSIS_ROWS),
                          interpolation=cv2.INTER_AREA)
    rows, cols = grey.shape
    top = int(rows * ROAD_FROM)
    edges = cv2.Canny(grey[top:], 50, 150)
    segments = cv2.HoughLinesP(edges, 1, np.pi / 180, threshold=max(8, rows // 12),
                               minLineLength=max(4, round(0.04 * rows)),
                               maxLineGap=max(1, round(0.02 * rows)))
    if segments is None:
        return None
    x1, y1, x2, y2 = segments.reshape(-1, 4).astype(np.float64).T
    y1, y2 = y1 + top, y2 + top
    dx, dy = x2 - x1, y2 - y1
    with np.errstate(divide="ignore", invalid="ignore"):
        slope = np.where(dx != 0, dy / np.where(dx != 0, dx, 1.0), np.inf)
    steep = (np.abs(slope) >= LANE_SLOPES[0]) & (np.abs(slope) <= LANE_SLOPES[1])
    middle = (x1 + x2) / 2
    length = np.hypot(dx, dy)
    # In image rows (y down) a left lane line falls to the right: negative slope.
    left = steep & (slope < 0) & (middle < 0.6 * cols)
    right = steep & (slope > 0) & (middle > 0.4 * cols)
    if not left.any() or not right.any():
        return None
    ma, xa, ya, la = (v[left][:, None] for v in (slope, x1, y1, length))
    mb, xb, yb, lb = (v[right][None] for v in (slope, x1, y1, length))
    # Where y = ya + ma (x - xa) meets y = yb + mb (x - xb); ma < 0 < mb, never parallel.
    x = (yb - ya + ma * xa - mb * xb) / (ma - mb)
    y = ya + ma * (x - xa)
    weight = la * lb
    keep = ((y > PLAUSIBLE_ROWS[0] * rows) & (y < PLAUSIBLE_ROWS[1] * rows)
            & (x > 0.2 * cols) & (x < 0.8 * cols))
    if not keep.any():
        return None
    return _densest_row(y[keep] / rows, weight[keep])


def _densest_row(rows, weights):
    """The weighted median of the crossings near their densest row.

    Pairs of a lane line with a car's edge or a shadow cross anywhere, while
    the pairs of lane lines cross at one row: the densest one (in bins of
    :data:`BIN` of the frame height, each with its neighbours), not the median
    of all, which those others pull away.
    """
    bins = np.floor(rows / BIN).astype(np.int64)
    bins -= bins.min()
    mass = np.bincount(bins, weights)
    smoothed = np.convolve(mass, np.ones(3), mode="same")
    peak = int(np.argmax(smoothed))
    near = np.abs(bins - peak) <= 1
    values, weights = rows[near], weights[near]
    order = np.argsort(values, kind="stable")
    cumulative = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cumulative, cumulative[-1] / 2)])


def estimate_horizon(frames):
    """The horizon of the camera that took ``frames`` (one frame, or a video's few).

    Parameters
    ----------
    frames : iterable of ndarray
        Frames of one camera (``None`` entries are skipped).

    Returns
    -------
    HorizonEstimate
        The median of the frames' own estimates, when at least
        :data:`MIN_FRAME_SHARE` of them (and one) have one.

    Raises
    ------
    TypeError
        For one frame passed on its own, not in a list.
    InputError
        For a frame a detector refuses (see :func:`frame_horizon`).
    """
    if isinstance(frames, np.ndarray) and (
            frames.ndim <= 2 or (frames.ndim == 3 and frames.shape[2] in (1, 3, 4))):
        # Iterated, one frame's pixel rows were taken for hundreds of frames too
        # small to have a horizon, and the estimate silently found none.  An
        # array of frames (N, H, W[, C]) is iterable as frames; a frame's shape is not.
        raise TypeError(f"frames must be an iterable of frames, got one array of shape "
                        f"{frames.shape}: pass [frame] for a single image")
    found, seen = [], 0
    for frame in frames:
        if frame is None:
            continue
        seen += 1
        fraction = frame_horizon(frame)
        if fraction is not None:
            found.append(fraction)
    if not found or len(found) < MIN_FRAME_SHARE * seen:
        return HorizonEstimate(None, len(found), seen)
    values = np.array(found)
    return HorizonEstimate(float(np.median(values)), len(found), seen,
                           (float(np.percentile(values, 10)), float(np.percentile(values, 90))))


def resolve_horizon(config, frames):
    """``config`` with an ``"auto"`` horizon replaced by the one ``frames`` show.

    Parameters
    ----------
    config : DetectorConfig
    frames : iterable of ndarray
        Frames of the camera (read only when the horizon is ``"auto"``).

    Returns
    -------
    config : DetectorConfig
        With a numeric horizon (:meth:`DetectorConfig.with_horizon`): the
        estimate, or the built-in default where none was found or the
        estimate lies within :data:`DEFAULT_SNAP` of it.
    estimate : HorizonEstimate or None
        ``None`` when ``config``'s horizon was already a number.
    """
    if not config.search.auto_horizon:
        return config, None
    estimate = estimate_horizon(frames)
    return searched_at(config, estimate), estimate


def searched_at(config, estimate):
    """``config`` searched at the horizon ``estimate`` gives: the estimate, or the
    built-in default where it found none or lies within :data:`DEFAULT_SNAP` of it."""
    fraction = estimate.fraction
    if fraction is None or abs(fraction - DEFAULT_HORIZON) < DEFAULT_SNAP:
        fraction = DEFAULT_HORIZON
    return config.with_horizon(fraction)


__all__ = ["HorizonEstimate", "estimate_horizon", "frame_horizon", "resolve_horizon",
           "searched_at"]
