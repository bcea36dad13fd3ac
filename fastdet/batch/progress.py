"""Progress of a batch on the terminal: videos done, and frames with the aggregate frame rate.

Tasks report the frames they have written as Dask events on a topic of
their own batch (``worker.log_event``); the client adds them up.  Nothing is
drawn when stderr is not a terminal or with ``--quiet``.
"""

from __future__ import annotations

import sys
import threading

from tqdm import tqdm


class BatchProgress:
    """Two tqdm bars: videos (of ``total``) and frames (with frames per second).

    Parameters
    ----------
    total : int
        Videos to process.
    enabled : bool
        Draw anything at all.
    """

    def __init__(self, total, enabled):
        self.enabled = enabled
        self._reported = {}
        self._lock = threading.Lock()
        self.videos = tqdm(total=total, desc="videos", unit=" video", disable=not enabled,
                           file=sys.stderr, position=0, leave=False)
        self.frames = tqdm(desc="frames", unit=" frame", disable=not enabled, file=sys.stderr,
                           position=1, leave=False)

    def on_event(self, event):
        """A task's report ``(time, {"key": job, "frames": written so far})``."""
        message = event[1]
        with self._lock:
            before = self._reported.get(message["key"], 0)
            self._reported[message["key"]] = max(before, message["frames"])
            if message["frames"] > before:
                self.frames.update(message["frames"] - before)

    def video_done(self):
        with self._lock:
            self.videos.update(1)

    def close(self):
        self.frames.close()
        self.videos.close()
