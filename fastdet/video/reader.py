"""Streaming video input (OpenCV's FFmpeg backend).

:class:`VideoReader` yields frames one at a time, so memory does not grow with
the video's length; it checks at opening that the file is a readable video
with at least one frame in the requested range, so every such problem is
reported before any output is created.
"""

from __future__ import annotations

import contextlib
import math
import os
from pathlib import Path

import cv2

from ..errors import InputError

#: Frame rate written when a video does not state a usable one.
FALLBACK_FPS = 25.0
#: Suffixes FFmpeg would open as a one-frame "video"; they are images.
IMAGE_SUFFIXES = frozenset({".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".gif",
                            ".ppm", ".pgm"})


@contextlib.contextmanager
def _quiet_stderr():
    # FFmpeg prints its own diagnostics (e.g. "moov atom not found") straight
    # to file descriptor 2 while probing a bad file; the user gets our
    # one-line error instead.
    try:
        saved = os.dup(2)
    except OSError:  # pragma: no cover - no stderr at all
        yield
        return
    try:
        with open(os.devnull, "wb") as devnull:
            os.dup2(devnull.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


class VideoReader:
    """Frames of a video file, decoded one at a time.

    Parameters
    ----------
    path : str or Path
    start : int
        Index of the first frame to yield (frames are numbered from 0).
    end : int, optional
        Index one past the last frame to yield; the video's end by default.

    Attributes
    ----------
    path : Path
    fps : float
        Frames per second stated by the file (``FALLBACK_FPS`` if it states
        none).
    size : tuple of int
        ``(width, height)``.
    frame_count : int or None
        Frames in the whole file as its header states them (``None`` when
        unknown; the header can be wrong, reading is what counts).
    start, end : int, int or None

    Raises
    ------
    InputError
        When the file is missing, not a video, holds no frames, or ``start``
        lies past its end.

    Examples
    --------
    >>> with VideoReader("clip.mp4", start=10) as video:   # doctest: +SKIP
    ...     for frame in video:
    ...         ...
    """

    def __init__(self, path, start=0, end=None):
        self.path = Path(path)
        self.start = int(start)
        self.end = None if end is None else int(end)
        if self.start < 0:
            raise InputError(f"--start must be >= 0, got {self.start}")
        if self.end is not None and self.end <= self.start:
            raise InputError(f"--end ({self.end}) must be greater than --start ({self.start})")
        if not self.path.exists():
            raise InputError(f"video not found: {self.path}")
        if not self.path.is_file():
            raise InputError(f"not a video file: {self.path}")
        if self.path.suffix.lower() in IMAGE_SUFFIXES:
            raise InputError(f"{self.path} is an image, not a video (use `fastdet detect`)")
        with _quiet_stderr():
            capture = cv2.VideoCapture(str(self.path), cv2.CAP_FFMPEG)
        if not capture.isOpened():
            raise InputError(f"cannot read {self.path} as a video (not a video file or corrupt)")
        self._capture = capture
        count = capture.get(cv2.CAP_PROP_FRAME_COUNT)
        self.frame_count = int(count) if math.isfinite(count) and count >= 0 else None
        fps = capture.get(cv2.CAP_PROP_FPS)
        self.fps = float(fps) if math.isfinite(fps) and 0 < fps < 1000 else FALLBACK_FPS
        try:
            self._first = self._read_first()
        except BaseException:
            capture.release()
            raise
        self.size = (self._first.shape[1], self._first.shape[0])
        self._index = self.start

    def _read_first(self):
        # Reading a frame is the only reliable test of "has frames": headers
        # may be missing or wrong.
        if self.start > 0:
            self._capture.set(cv2.CAP_PROP_POS_FRAMES, self.start)
            if int(self._capture.get(cv2.CAP_PROP_POS_FRAMES)) != self.start:
                # The container cannot seek exactly: decode up to the start.
                self._capture.set(cv2.CAP_PROP_POS_FRAMES, 0)
                for _ in range(self.start):
                    if not self._capture.grab():
                        break
        ok, frame = self._capture.read()
        if ok and frame is not None:
            return frame
        if self.start == 0:
            raise InputError(f"{self.path} holds no frames")
        total = "" if self.frame_count is None else f" ({self.frame_count} frames)"
        raise InputError(f"--start {self.start} is past the end of {self.path}{total}")

    @property
    def first_frame(self):
        """The first frame to yield, read at opening (``None`` once iteration has begun)."""
        return self._first

    @property
    def expected_frames(self):
        """Frames this reader should yield, from the header (``None`` if unknown)."""
        last = self.frame_count
        if self.end is not None:
            last = self.end if last is None else min(last, self.end)
        return None if last is None else max(last - self.start, 0)

    def __iter__(self):
        """Yield BGR uint8 frames of shape (height, width, 3), in order."""
        return self.frames()

    def frames(self, skip=None):
        """Yield the frames in order, optionally without converting some.

        Parameters
        ----------
        skip : callable, optional
            Called before each frame; when it returns True the frame is
            decoded (the codec needs every frame) but not converted to BGR,
            and ``None`` is yielded in its place, which saves about a sixth
            of the decoding time.

        Yields
        ------
        ndarray of uint8, shape (height, width, 3), or None
        """
        if self._capture is None:
            raise InputError(f"{self.path} is closed")
        if self._first is not None:
            frame, self._first = self._first, None
            self._index += 1
            yield frame
        while self.end is None or self._index < self.end:
            if skip is not None and skip():
                if not self._capture.grab():
                    return
                frame = None
            else:
                ok, frame = self._capture.read()
                if not ok or frame is None:
                    return
            self._index += 1
            yield frame

    def close(self):
        """Release the decoder (idempotent)."""
        if self._capture is not None:
            self._capture.release()
            self._capture = None
            self._first = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __del__(self):
        with contextlib.suppress(Exception):
            self.close()
