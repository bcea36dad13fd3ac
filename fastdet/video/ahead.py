"""Frame-level parallelism: the detector's hits of upcoming frames, computed ahead.

Splitting one frame over threads (:class:`~fastdet.detector.detector.Detector`
with ``threads=2``) leaves cores idle: a frame's scales end unevenly, its
heat and boxes are serial, and every hand-over between threads costs a
wake-up (on the 2-core machines here 2 threads gave 1.4-1.7 times one
thread).  A video has frames to spare, though: without patch tracking the
frames a :class:`~fastdet.video.pipeline.VideoPipeline` searches are known in
advance (:meth:`~fastdet.video.pipeline.VideoPipeline.searches_ahead`), and a
frame's hits (the scoring of every window, nearly all of the work) do not
depend on the frames before it.  So ``workers`` single-thread detectors
score that many upcoming frames at once, each a whole frame, and the
pipeline's temporal steps (heat smoothing, boxes, tracks) take their hits
in frame order: the results are those of a plain loop (a test).

With patch tracking, whether a frame is searched depends on the frames
before it, and the frames go through one at a time as before.
"""

from __future__ import annotations

import collections
import threading
import weakref

from ..detector.detector import Detector
from .source import MAX_THREADS

#: Frames looked ahead per frame to search at most: a search period
#: (``every``) longer than this scores fewer frames at once.
MAX_PERIOD = 8

#: Most frames scored at once (:data:`fastdet.video.source.MAX_THREADS`, as
#: ``--threads``): each is a detector and a thread, and the look-ahead holds
#: about ``2 * workers`` frames to search.
MAX_WORKERS = MAX_THREADS

#: Frames to search queued per thread scoring them, besides the calling
#: thread's next one.  The calling thread queues frames only between the
#: frames it scores itself, and it also runs every frame's temporal steps, so a
#: helper finishes a frame and wants the next before the queue is topped up:
#: with one frame each, the helper on the 2-core machines here waited 0.1-0.5
#: ms a frame for work (AMD EPYC Zen 4, test video), with two 0.005 ms.
QUEUED_PER_THREAD = 2

# Helper detectors kept between runs, per pipeline detector: a new one's first
# frame costs about 4 ms more than the next (its work arrays are made).
_IDLE_HELPERS = weakref.WeakKeyDictionary()
_HELPERS_LOCK = threading.Lock()


def _borrow_helpers(detector, count):
    """``count`` single-thread detectors with ``detector``'s model and config, idle
    ones first; each is used by one run at a time (see :func:`_return_helpers`)."""
    with _HELPERS_LOCK:
        idle = _IDLE_HELPERS.get(detector, [])
        same = [h for h in idle if h.model is detector.model and h.config == detector.config]
        _IDLE_HELPERS[detector] = same[count:]   # helpers of an older config are dropped
        helpers = same[:count]
    helpers += [Detector(detector.model, detector.config, threads=1, preload=False)
                for _ in range(count - len(helpers))]
    return helpers


def _return_helpers(detector, helpers):
    with _HELPERS_LOCK:
        _IDLE_HELPERS.setdefault(detector, []).extend(helpers)


def can_look_ahead(pipeline):
    """Whether :func:`process_ahead` can score frames of ``pipeline`` ahead."""
    return isinstance(pipeline.detector, Detector) and pipeline.searches_ahead(1) is not None


def _as_is(item, wanted):
    return item


def process_ahead(pipeline, items, workers, to_frame=_as_is):
    """Run ``pipeline`` over ``items``, scoring up to ``workers`` frames at once.

    Parameters
    ----------
    pipeline : VideoPipeline
        Its detector must be a :class:`Detector`; the workers are
        single-thread detectors with its model and config (the calling
        thread's is the pipeline's own detector if that has one thread).
    items : iterable
        In frame order.
    workers : int
        Frames scored at once; below 2, or where the pipeline cannot look
        ahead (:func:`can_look_ahead`), each frame is processed in turn.
    to_frame : callable, optional
        ``to_frame(item, wanted)``: the frame of an item, as
        :meth:`~fastdet.video.pipeline.VideoPipeline.process` takes it;
        ``wanted`` says whether the pipeline will look at it (if not, it may
        return ``None`` and save a decode or a conversion).  Default: the
        items are the frames.

    Yields
    ------
    item, frame, Detections
        In the order of ``items``; ``frame`` is what ``to_frame`` gave.
        Closing the generator lets the frames being scored finish and stops
        the worker threads.
    """
    if workers < 2 or not can_look_ahead(pipeline):
        for item in items:
            frame = to_frame(item, pipeline.wants_frame)
            yield item, frame, pipeline.process(frame)
        return
    detector = pipeline.detector
    # The calling thread scores with the pipeline's own detector when it is
    # single-threaded (as fastdet run makes it for frames at once), else
    # with one of its own; each helper thread has its own.
    own = detector if detector.threads == 1 else None
    borrowed = _borrow_helpers(detector, workers - (own is not None))
    detectors = ([own] if own is not None else []) + borrowed
    queue = _Lookahead()
    helpers = [threading.Thread(target=queue.score_ahead, args=(helper,), daemon=True,
                                name=f"fastdet-frame-{k}")
               for k, helper in enumerate(detectors[1:], 1)]
    for thread in helpers:
        thread.start()
    try:
        source = iter(items)
        more = True
        while True:
            # Look ahead until QUEUED_PER_THREAD * workers + 1 frames to
            # search are queued (with --every N, N times as many frames), so
            # that no thread waits for work.
            queued = QUEUED_PER_THREAD * workers
            while (more and queue.searched <= queued
                   and len(queue) < (queued + 1) * MAX_PERIOD):
                try:
                    item = next(source)
                except StopIteration:
                    more = False
                    break
                wanted = pipeline.searches_ahead(len(queue) + 1)[-1]
                frame = to_frame(item, wanted)
                queue.append(item, frame, wanted and frame is not None)
            if not len(queue):
                return
            entry = queue.popleft()
            # Whichever thread is free scores the first frame nobody took; this
            # one also runs the temporal steps in order, so the work balances
            # itself between it and the helpers.
            hits = queue.take(entry, detectors[0].hits) if entry.wanted else None
            yield entry.item, entry.frame, pipeline.process(entry.frame, hits=hits)
    finally:
        # Frames not started are dropped; the helpers finish the frame they
        # are scoring (the caller's arrays) before this returns.
        queue.close()
        for thread in helpers:
            thread.join()
        _return_helpers(detector, borrowed)


class _Entry:
    """One queued frame: claimed by one thread, which scores it and sets ``done``."""

    __slots__ = ("item", "frame", "wanted", "claimed", "done", "hits", "error")

    def __init__(self, item, frame, wanted):
        self.item, self.frame, self.wanted = item, frame, wanted
        self.claimed = False
        self.done = threading.Event()
        self.hits = self.error = None

    def score(self, hits_of):
        # An error is kept and raised when the frame's turn comes, after the
        # frames before it; a KeyboardInterrupt (the calling thread's own
        # scoring) goes straight through, the frame left unscored.
        try:
            self.hits = hits_of(self.frame)
        except Exception as exc:  # noqa: BLE001 - raised again on the calling thread
            self.error = exc
        finally:
            self.done.set()


class _Lookahead:
    """The queued frames; helper threads claim the first unclaimed one to score."""

    def __init__(self):
        self._entries = collections.deque()
        self._changed = threading.Condition()
        self._closed = False
        self.searched = 0

    def __len__(self):
        return len(self._entries)

    def append(self, item, frame, wanted):
        with self._changed:
            self._entries.append(_Entry(item, frame, wanted))
            self.searched += wanted
            self._changed.notify()

    def popleft(self):
        with self._changed:
            entry = self._entries.popleft()
            self.searched -= entry.wanted
            return entry

    def _claim_first(self):
        # With the lock held: the first queued frame to score that nobody took.
        entry = next((e for e in self._entries if e.wanted and not e.claimed), None)
        if entry is not None:
            entry.claimed = True
        return entry

    def take(self, entry, hits_of):
        """A popped frame's hits, scoring with ``hits_of`` meanwhile.

        Scored here unless a helper claimed it; while a helper is still at
        it, this thread scores later queued frames instead of waiting (so
        no thread idles while there is a frame to score).  A helper's error
        is raised here.
        """
        with self._changed:
            mine = not entry.claimed
            entry.claimed = True
        if mine:
            entry.score(hits_of)
        while not entry.done.is_set():
            with self._changed:
                other = self._claim_first()
            if other is None:
                entry.done.wait()
                break
            other.score(hits_of)
        if entry.error is not None:
            raise entry.error
        return entry.hits

    def score_ahead(self, detector):
        """A helper thread: score the first unclaimed frame, again, until closed."""
        while True:
            with self._changed:
                entry = None
                while entry is None and not self._closed:
                    entry = self._claim_first()
                    if entry is None:
                        self._changed.wait()
                if entry is None:
                    return
            entry.score(detector.hits)

    def close(self):
        with self._changed:
            self._closed = True
            self._changed.notify_all()
