"""A video's ``[search] horizon = "auto"``, resolved before its first frame is searched.

The horizon is the camera's, not the frame's: one value per video, estimated
(:func:`fastdet.detector.horizon.estimate_horizon`) from the frames of the
file's first seconds, whatever frame a run starts at, so that every segment
of a batch and the whole-video run search the same rows.  A live source (a
camera, a stream) is estimated from its first frame, the only one read
before the run starts.
"""

from __future__ import annotations

import collections
import os
import threading

from ..detector.horizon import FRAME_STEP, FRAMES, estimate_horizon
from .source import VideoSource


def horizon_frames(video):
    """The frames a video's horizon is estimated from.

    Parameters
    ----------
    video : VideoSource
        Open; a file is read again from its start by a source of its own,
        so ``video`` itself is not advanced.

    Returns
    -------
    list of ndarray
        Every :data:`~fastdet.detector.horizon.FRAME_STEP`-th of a file's first
        ``FRAME_STEP * FRAMES`` frames (ten seconds at 25 fps: a road's first
        seconds may climb or bend); a live source's first frame.
    """
    if video.kind != "file":
        first = video.first_frame
        return [] if first is None else [first]
    wanted = lambda index: index % FRAME_STEP == 0  # noqa: E731
    with VideoSource(video.path, 0, FRAME_STEP * FRAMES, threads=1) as start:
        # The frames in between stay undecoded where the codec allows.
        return [frame for index, frame in enumerate(start.frames(needed=wanted))
                if wanted(index) and frame is not None]


#: Files' estimates kept, the latest first: a batch worker runs a video's segments
#: one after another, and each would read the same frames again (0.2-0.5 s).
KEPT_ESTIMATES = 32
_estimates = collections.OrderedDict()
_estimates_lock = threading.Lock()


def video_horizon(video):
    """The horizon estimate of ``video``'s frames (:func:`horizon_frames`).

    A file's is kept, keyed by its path, size and modification time, so the
    segments of one video read its frames once per process.
    """
    if video.kind != "file":
        return estimate_horizon(horizon_frames(video))
    stat = os.stat(video.path)
    key = (str(video.path.resolve()), stat.st_size, stat.st_mtime_ns)
    with _estimates_lock:
        if key in _estimates:
            _estimates.move_to_end(key)
            return _estimates[key]
    estimate = estimate_horizon(horizon_frames(video))
    with _estimates_lock:
        _estimates[key] = estimate
        while len(_estimates) > KEPT_ESTIMATES:
            _estimates.popitem(last=False)
    return estimate


def resolve_video_horizon(detector, video, log=None):
    """Give ``detector`` the horizon of ``video`` when its configured one is ``"auto"``.

    Parameters
    ----------
    detector : Detector or object
        Anything without an ``auto_horizon`` (a stand-in detector) is left alone.
    video : VideoSource
    log : callable, optional
        Gets the estimate's one-line description.

    Returns
    -------
    HorizonEstimate or None
        ``None`` when the configured horizon is a number (no frame is read).
    """
    if not getattr(detector, "auto_horizon", False):
        return None
    estimate = video_horizon(video)
    detector.take_horizon(estimate)
    if log is not None:
        log(f"{video.name}: {estimate.describe()}; searching at "
            f"{detector.config.search.horizon:.3f}")
    return estimate
