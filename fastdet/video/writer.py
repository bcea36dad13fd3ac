"""Atomic video output (OpenCV's FFmpeg backend), optionally encoded on a background thread."""

from __future__ import annotations

import queue
import threading

import cv2
import numpy as np

from ..errors import InputError
from ..files.atomic import StagedFile

#: Codec of written videos: MPEG-4 Part 2, which every OpenCV build can encode.
FOURCC = "mp4v"


class VideoWriter(StagedFile):
    """An MPEG-4 video written atomically, optionally encoded on a background thread.

    Frames go to a temporary file beside ``path``; :meth:`close` finishes the
    file and renames it to ``path``.  Used as a context manager it also does
    so when the block is left by ``KeyboardInterrupt`` (keeping every frame
    written so far), and deletes the temporary file on any other exception.
    A video without any frame is not a playable file and is never kept.

    Parameters
    ----------
    path : str or Path
        Destination; its suffix chooses the container (``.mp4``, ``.avi``, ...).
    fps : float
    size : tuple of int
        ``(width, height)`` of every frame.
    background : bool
        Encode on a separate thread (OpenCV releases the GIL while encoding),
        so encoding overlaps the caller's work when a second core is free.
        The writer then holds on to each frame until it is encoded: do not
        modify a frame after passing it to :meth:`write`.

    Raises
    ------
    InputError
        When the destination cannot be written.
    """

    #: Frames waiting for the background encoder; bounds the memory it holds.
    QUEUE_FRAMES = 4

    def __init__(self, path, fps, size, background=False):
        super().__init__(path)
        self.size = (int(size[0]), int(size[1]))
        self.fps = float(fps)
        self.frames = 0
        self._writer = cv2.VideoWriter(str(self.temporary), cv2.CAP_FFMPEG,
                                       cv2.VideoWriter_fourcc(*FOURCC), self.fps, self.size)
        if not self._writer.isOpened():
            self.discard()
            raise InputError(f"cannot write a video to {self.path} "
                             f"(unsupported suffix {self.path.suffix!r}?)")
        self._queue = self._thread = self._failure = None
        if background:
            self._queue = queue.Queue(maxsize=self.QUEUE_FRAMES)
            self._thread = threading.Thread(target=self._encode_queued, daemon=True,
                                            name="fastdet-video-encoder")
            self._thread.start()

    def _encode_queued(self):
        while True:
            frame = self._queue.get()
            if frame is None:
                return
            if self._failure is None:
                try:
                    self._writer.write(frame)
                except Exception as exc:  # noqa: BLE001 - reported by the next write/close
                    self._failure = exc

    def write(self, frame):
        """Append one BGR uint8 frame of the writer's size."""
        if frame.shape[:2] != (self.size[1], self.size[0]) or frame.dtype != np.uint8:
            raise InputError(f"frame of shape {frame.shape} does not fit a "
                             f"{self.size[0]}x{self.size[1]} video")
        self._raise_failure()
        if self._queue is None:
            self._writer.write(frame)
        else:
            self._queue.put(frame)
        self.frames += 1

    def _raise_failure(self):
        if self._failure is not None:
            raise InputError(f"cannot write a video to {self.path}: {self._failure}")

    def _stop_encoder(self):
        if self._thread is not None and self._thread.is_alive():
            self._queue.put(None)
            self._thread.join()

    def close(self):
        """Finish the video and move it into place (a video without frames is discarded)."""
        if self.frames == 0:
            self.discard()
        else:
            super().close()

    def _finish(self):
        self._stop_encoder()
        self._writer.release()
        self._raise_failure()

    def _abandon(self):
        if self._thread is not None:
            self._failure = self._failure or InputError("discarded")  # skip what is queued
        self._stop_encoder()
        self._writer.release()
