"""The pipelined run: decode, detect+track, draw+encode and the detections file as stages.

Each stage is a thread; bounded queues join them, so frames stay in order and
memory stays flat whatever the video's length::

    decode ──q──> detect+track ──q──> draw+encode      (with a video output)
                               └─q──> detections file  (and the callback)

Decoding, encoding, colour conversion and the detector's kernels release
the GIL, so the stages overlap on the cores.  The stage threads are planned
with the codecs' and the detector's own threads (:func:`plan_threads`) so
that together they fit the cores instead of stacking.

Stopping
--------
* An exception in any stage stops every stage; :meth:`Conveyor.run` raises
  it once all have stopped.
* :meth:`Conveyor.stop` (the first Ctrl-C or SIGTERM) stops decoding; the
  frames already decoded flow through to both outputs, so both end with the
  same, complete frames.
* :meth:`Conveyor.abort` (a second signal) stops every stage at once.
"""

from __future__ import annotations

import contextlib
import math
import numbers
import queue
import signal
import threading
import time
from dataclasses import dataclass, field

import numba
import numpy as np
from av.video.reformatter import VideoReformatter

from ..detector.scoring import STAGES
from ..errors import InputError
from ..viz.draw import debug_frame, draw_detections_yuv420
from .ahead import process_ahead
from .frame_arrays import FrameConverter, plane_view
from .source import MAX_THREADS
from .standard_output import ReaderGone

#: Frames each queue holds: enough to ride out one slow frame, few enough for flat memory.
QUEUE_FRAMES = 4
#: Decoded frames the detector's queue may hold while the kernels load (the
#: decoder starts before the warm-up; 24 1280x720 frames are about 33 MB).
WARM_UP_FRAMES = 24
#: Items without pixels (frames left undecoded or not looked at) a frame
#: queue holds besides its frames.
PLACEHOLDERS = 64
#: Seconds a blocked stage waits before looking at the stop/abort flags again.
POLL_SECONDS = 0.1
#: Marks the end of the frame stream.
END = object()

#: Per-frame CPU milliseconds of each kind of work on one 1280x720 frame on one core, as
#: measured on the development machine (README, "Video"); only their ratios matter.
_DECODE_MS, _SEARCH_MS, _ENCODE_MS = 3.7, 4.5, 4.5


class Aborted(Exception):
    """Raised inside a stage when another stage failed or the run was aborted."""


@dataclass(frozen=True)
class ThreadPlan:
    """Threads given to each kind of work so that together they fit ``cores``."""

    cores: int
    decoder: int
    detector: int
    encoder: int
    #: Frames the detector's threads score at once, one each (frame-level
    #: parallelism, :mod:`fastdet.video.ahead`); 1: they share each frame.
    frames_at_once: int = 1

    def describe(self):
        """One line for ``--verbose``."""
        encoder = f", encoder {self.encoder}" if self.encoder else ""
        how = (f" ({self.frames_at_once} frames at once, one thread each)"
               if self.frames_at_once > 1 else "")
        return (f"threads: {self.cores} cores -> decoder {self.decoder}, detector "
                f"{self.detector}{how}{encoder} (plus one light thread per stage)")


def run_cores(threads=None):
    """The cores a run may keep busy: ``threads``, checked.

    Parameters
    ----------
    threads : int, optional
        ``--threads`` (``None``: ``NUMBA_NUM_THREADS``, all cores by default).
        More than the machine has is allowed (a plan for another machine),
        up to :data:`MAX_THREADS`.

    Returns
    -------
    int

    Raises
    ------
    InputError
        For anything but a whole number from 1 to :data:`MAX_THREADS` (0 and
        2.5 were taken as the default and as 2; 100000 planned tens of
        thousands of codec threads: "can't start new thread", or a decoder
        that gave no frame and a process that never exited).
    """
    if threads is None:
        return numba.config.NUMBA_NUM_THREADS
    if isinstance(threads, bool) or not isinstance(threads, numbers.Integral):
        raise InputError(f"--threads must be a whole number of cores, got {threads!r}")
    if not 1 <= threads <= MAX_THREADS:
        raise InputError(f"--threads must be 1-{MAX_THREADS}, got {threads}")
    return int(threads)


def plan_threads(cores, video=True, search_fraction=1.0):
    """Share ``cores`` between the decoder, the detector and the encoder by their load.

    Parameters
    ----------
    cores : int
        Threads the whole run may keep busy.
    video : bool
        Whether an annotated video is encoded.
    search_fraction : float
        Share of frames fully searched (``1 / every``).

    Returns
    -------
    ThreadPlan
        Each part's share of the cores is its share of the per-frame CPU time,
        rounded, and at least one thread; the heaviest part, which bounds the
        run, gets its share rounded up if cores are left.  On 2 cores:
        decoder, detector and encoder one each with a video output; without
        one, decoder and detector one each (every frame searched) or the
        decoder two (``--every 5``, where detection leaves its core mostly
        idle).  Measured on the 2-core development machine (README, "Video").
    """
    cores = max(1, int(cores))
    loads = {"decoder": _DECODE_MS, "detector": _SEARCH_MS * max(search_fraction, 0.05),
             "encoder": _ENCODE_MS if video else 0.0}
    total = sum(loads.values())
    shares = {name: cores * load / total for name, load in loads.items()}
    threads = {name: max(1, round(share)) if share else 0 for name, share in shares.items()}
    # The heaviest part bounds the run: it may also take cores the others leave
    # idle, but only idle ones.  (Given a second detector thread beside a busy
    # decoder on 2 cores, the run was slower: 0.67 R against 0.74 R.)
    heaviest = max(shares, key=shares.get)
    spare = cores - sum(threads.values())
    threads[heaviest] += max(0, min(spare, math.ceil(shares[heaviest]) - threads[heaviest]))
    return ThreadPlan(cores, threads["decoder"], threads["detector"], threads.get("encoder", 0))


@dataclass
class StageClock:
    """Where one stage's time went: CPU of its thread, and waiting on its neighbours."""

    cpu: float = 0.0
    starved: float = 0.0   # waiting for input
    blocked: float = 0.0   # waiting for room downstream


@dataclass
class StageTimes:
    """Clocks of every stage of a run, by stage name, and the process's CPU."""

    stages: dict = field(default_factory=dict)
    process_cpu: float = 0.0

    def bound(self):
        """The stage that limited the run: the one that waited least."""
        if not self.stages:
            return None
        return min(self.stages, key=lambda n: self.stages[n].starved + self.stages[n].blocked)


def warm_up_queue_frames(frame_size):
    """Frames the detector's queue holds while the kernels load: ``WARM_UP_FRAMES``
    at 1280x720, fewer for larger frames (the same memory), never below ``QUEUE_FRAMES``."""
    width, height = frame_size
    return max(QUEUE_FRAMES, min(WARM_UP_FRAMES,
                                 int(WARM_UP_FRAMES * 1280 * 720 / max(width * height, 1))))


class FrameQueue(queue.Queue):
    """A queue of ``(index, frame, ...)`` items bounded by the frames that carry pixels.

    Items whose frame is ``None`` (placeholders of frames nobody looks at)
    hold no memory to speak of: up to ``placeholders`` of them wait besides
    ``frames`` items with pixels, so a decoder that leaves most frames out
    is not held back by a count of items.  ``frames`` may be changed while
    the queue is in use (a smaller bound applies from the next ``put``).
    """

    def __init__(self, frames=QUEUE_FRAMES, placeholders=PLACEHOLDERS):
        super().__init__()
        self.frames = frames
        self.placeholders = placeholders
        self._carrying = 0

    @staticmethod
    def _carries(item):
        return isinstance(item, tuple) and item[1] is not None

    def _no_room_for(self, item):
        if self._carries(item):
            return self._carrying >= self.frames
        return len(self.queue) - self._carrying >= self.placeholders

    def put(self, item, block=True, timeout=None):
        with self.not_full:
            deadline = None if timeout is None else time.monotonic() + timeout
            while self._no_room_for(item):
                if not block:
                    raise queue.Full
                if deadline is None:
                    self.not_full.wait()
                else:
                    remaining = deadline - time.monotonic()
                    if remaining <= 0:
                        raise queue.Full
                    self.not_full.wait(remaining)
            self._put(item)
            self.unfinished_tasks += 1
            self.not_empty.notify()

    def _put(self, item):
        self._carrying += self._carries(item)
        self.queue.append(item)

    def _get(self):
        item = self.queue.popleft()
        self._carrying -= self._carries(item)
        return item


class Conveyor:
    """Stage threads joined by bounded queues, with shared stop and abort flags.

    Stage functions receive the conveyor and use :meth:`get` and :meth:`put`
    on its queues; both give up with :class:`Aborted` when any stage failed.
    """

    def __init__(self):
        self.stopping = threading.Event()
        self._aborting = threading.Event()
        self._threads = []
        self._errors = []
        self._unread = set()    # queues whose consumer has stopped
        self._named = {}
        self.times = StageTimes()
        #: True while :meth:`run` waits for the stages.
        self.running = False

    # -- queues -----------------------------------------------------------------
    def queue(self, size=QUEUE_FRAMES):
        """A new bounded queue between two stages."""
        return queue.Queue(maxsize=size)

    def frame_queue(self, frames=QUEUE_FRAMES):
        """A new queue of decoded frames, bounded by the frames with pixels (:class:`FrameQueue`)."""
        return FrameQueue(frames)

    def get(self, source, clock):
        """The next item of ``source``; raises :class:`Aborted` once the run aborts."""
        start = time.perf_counter()
        try:
            while True:
                if self._aborting.is_set():
                    raise Aborted
                try:
                    return source.get(timeout=POLL_SECONDS)
                except queue.Empty:
                    continue
        finally:
            clock.starved += time.perf_counter() - start

    def put(self, target, item, clock):
        """Put ``item`` on ``target``, waiting for room; raises :class:`Aborted` on abort.

        An item for a stage that has stopped reading is dropped.
        """
        start = time.perf_counter()
        try:
            while True:
                if self._aborting.is_set():
                    raise Aborted
                if id(target) in self._unread:
                    return
                try:
                    target.put(item, timeout=POLL_SECONDS)
                    return
                except queue.Full:
                    continue
        finally:
            clock.blocked += time.perf_counter() - start

    # -- stages -----------------------------------------------------------------
    def add(self, name, function, *args, inbox=None):
        """Run ``function(clock, *args)`` on its own thread once :meth:`run` starts.

        ``inbox`` is the queue the stage reads: once the stage ends, items put
        there are dropped instead of waiting for room forever.
        """
        clock = self.times.stages[name] = StageClock()

        def body():
            cpu = time.thread_time()
            try:
                function(clock, *args)
            except Aborted:
                pass
            except BaseException as exc:  # noqa: BLE001 - re-raised by run()
                self._errors.append(exc)
                self.abort()
            finally:
                if inbox is not None:
                    self._unread.add(id(inbox))
                clock.cpu = time.thread_time() - cpu

        thread = threading.Thread(target=body, name=f"fastdet-{name}", daemon=True)
        self._threads.append(thread)
        self._named[name] = thread

    def start(self, name):
        """Start one stage before :meth:`run` (which then starts the others).

        Until :meth:`run`, only :meth:`cancel` stops it.
        """
        self._named[name].start()

    def cancel(self):
        """Abort, and wait for the stages already started (a run that will not start)."""
        self.abort()
        for thread in self._threads:
            if thread.ident is not None:
                thread.join()

    def stop(self):
        """Stop reading input; what was read still goes through every stage."""
        self.stopping.set()

    def abort(self):
        """Stop every stage now."""
        self.stopping.set()
        self._aborting.set()

    @property
    def aborted(self):
        return self._aborting.is_set()

    def run(self, on_tick=None):
        """Start every stage and wait for all of them.

        Parameters
        ----------
        on_tick : callable, optional
            Called about 10 times a second on the calling thread while the
            stages run (progress display); signal handlers run between ticks.

        Raises
        ------
        BaseException
            The first error of any stage, once every stage has stopped.
        """
        cpu = time.process_time()
        self.running = True
        for thread in self._threads:
            if thread.ident is None:
                thread.start()
        try:
            for thread in self._threads:
                while thread.is_alive():
                    thread.join(POLL_SECONDS)
                    if on_tick is not None:
                        on_tick()
        except BaseException:
            self.abort()
            for thread in self._threads:
                thread.join()
            raise
        finally:
            self.running = False
            self.times.process_cpu = time.process_time() - cpu
        if self._errors:
            raise self._errors[0]


# -- the stages of a run -------------------------------------------------------------
def _debug_view(frame, detections, pipeline):
    """The frame with boxes, the live heat map inset and the detector's stage timings."""
    heat = np.zeros(frame.shape[:2], np.float32)
    if pipeline.last_heat is not None:
        region, (x0, y0) = pipeline.last_heat
        h = min(region.shape[0], heat.shape[0] - y0)
        w = min(region.shape[1], heat.shape[1] - x0)
        if h > 0 and w > 0:
            heat[y0:y0 + h, x0:x0 + w] = region[:h, :w]
    timings = pipeline.detector.timings
    timings_ms = {stage: 1e3 * timings[stage] for stage in STAGES if stage in timings}
    # A fixed scale keeps the inset's brightness from pumping with each frame's peak.
    scale = 4 * pipeline.detector.config.heat.threshold or None
    return debug_frame(frame, detections, heat, timings_ms, heat_max=scale)


def decode(clock, conveyor, source, outbox, realtime, stats, rows=None, needed=None):
    """Decoded frames onto ``outbox``; with ``realtime``, never wait: drop the oldest.

    With ``rows``, each frame's rows ``(y0, y1)`` are also converted to BGR
    here (:class:`~fastdet.video.frame_arrays.FrameConverter`) and travel
    with it: for runs that search every frame, where the detector's thread
    bounds the run and this one has time to spare.  With ``needed``
    (``needed(index) -> bool``), frames nothing looks at may stay undecoded
    (:meth:`~fastdet.video.source.VideoSource.decoded_frames`) and travel as
    ``None``, as do those decoded only as references for others.
    """
    frames = source.decoded_frames(needed)
    converter = FrameConverter() if rows is not None else None
    paced = realtime and not source.live
    started = first_pts = None
    try:
        for index, frame in enumerate(frames, source.start):
            if conveyor.stopping.is_set():
                break
            if paced and frame.pts is not None:
                # A file read "live": at its own frame rate.
                started = time.perf_counter() if started is None else started
                first_pts = frame.pts if first_pts is None else first_pts
                delay = started + float((frame.pts - first_pts) * source.time_base)
                # The remaining wait is read once: read twice, the clock may pass
                # the deadline between the test and the sleep.  A stop ends it early.
                remaining = delay - time.perf_counter()
                if remaining > 0:
                    conveyor.stopping.wait(remaining)
            if needed is not None and frame is not None and not needed(index):
                # Decoded but not looked at (a reference for other frames, or any
                # frame once the skipping stopped): it travels without its pixels.
                frame = None
            bgr = (converter.to_bgr(frame, rows)
                   if converter is not None and frame is not None else None)
            if realtime:
                stats.dropped += _put_newest(outbox, (index, frame, bgr))
            else:
                conveyor.put(outbox, (index, frame, bgr), clock)
    finally:
        frames.close()
    stats.ended = source.ended
    stats.undecoded = source.frames_left_undecoded
    stats.damage = source.damage.describe(source.frames_read) or None
    conveyor.put(outbox, END, clock)


def _put_newest(outbox, item):
    """Put ``item`` without waiting, dropping the oldest queued frame if full; frames dropped."""
    dropped = 0
    while True:
        try:
            outbox.put_nowait(item)
            return dropped
        except queue.Full:
            with contextlib.suppress(queue.Empty):
                outbox.get_nowait()
                dropped += 1


def detect(clock, conveyor, inbox, outboxes, pipeline, rows, debug_view, first_output, stats,
           workers=1):
    """Detection and tracking, in frame order; warm-up frames only update the state.

    With ``workers`` of 2 or more, that many upcoming frames are scored at
    once (:func:`~fastdet.video.ahead.process_ahead`).
    """
    converter = FrameConverter()

    def incoming():
        while True:
            item = conveyor.get(inbox, clock)
            if item is END:
                return
            yield item

    def to_bgr(item, wanted):
        if item[2] is not None or item[1] is None:
            return item[2]
        if debug_view or wanted:
            return converter.to_bgr(item[1], None if debug_view else rows)
        return None

    results = process_ahead(pipeline, incoming(), 1 if debug_view else workers, to_bgr)
    try:
        for (index, frame, _), bgr, detections in results:
            if index < first_output:
                continue
            picture = _debug_view(bgr, detections, pipeline) if debug_view else None
            for outbox in outboxes:
                conveyor.put(outbox, (index, frame, picture, detections), clock)
    except KeyboardInterrupt:
        # Raised on this thread (e.g. by a callback of the caller's pipeline):
        # a stop like Ctrl-C; the frames before it still reach the outputs.
        stats.interrupted = stats.interrupted or signal.SIGINT
        conveyor.stop()
    finally:
        results.close()
    stats.full_searches = pipeline.full_searches
    for outbox in outboxes:
        conveyor.put(outbox, END, clock)


def encode(clock, conveyor, inbox, sink, keep_timestamps=True):
    """Boxes drawn on the decoded planes (or the debug picture), encoded in order.

    The frames keep their timestamps (a file's start offset included), or
    with ``keep_timestamps`` false start at 0 with their spacing kept.
    """
    reformatter = VideoReformatter()
    origin = None
    while True:
        item = conveyor.get(inbox, clock)
        if item is END:
            return
        _, frame, picture, detections = item
        pts = None
        if frame.pts is not None:
            if origin is None:
                origin = 0 if keep_timestamps else frame.pts
            pts = frame.pts - origin
        if picture is not None:
            if not _written(conveyor, sink, picture, pts):
                return
            continue
        if frame.format.name != "yuv420p":
            # E.g. a camera's full-range yuvj420p: to what the encoder takes.
            frame = reformatter.reformat(frame, format="yuv420p", dst_color_range="MPEG",
                                         threads=1)
        if len(detections):
            # The decoder may still read this picture as a reference: draw on a copy.
            frame.make_writable()
            draw_detections_yuv420(plane_view(frame, 0), plane_view(frame, 1),
                                   plane_view(frame, 2), detections, bt709=sink.bt709)
        if not _written(conveyor, sink, frame, pts):
            return


def _written(conveyor, sink, frame, pts):
    """Encode one frame; ``False`` once standard output's reader has gone (``| head``).

    Like Ctrl-C, that stops reading, and the other output is completed with
    the frames read so far.
    """
    try:
        sink.write(frame, pts)
    except ReaderGone:
        conveyor.stop()
        return False
    return True


def report(clock, conveyor, inbox, writer, callback, stats):
    """The detections file, the caller's callback and the counts, in frame order."""
    while True:
        item = conveyor.get(inbox, clock)
        if item is END:
            return
        index, _, _, detections = item
        if writer is not None and not writer.reader_gone:
            try:
                writer.write(index, detections)
            except ReaderGone:
                conveyor.stop()     # as Ctrl-C does; the frames read still reach the video
        if callback is not None:
            callback(index, detections)
        stats.frames += 1
        stats.boxes += len(detections)
        if detections.track_id is not None:
            stats.track_ids.update(detections.track_id.tolist())
