"""The client side of a batch: which videos to run, their tasks, and their manifest records.

:class:`BatchRun` skips the videos the manifest says are done, submits one
task per video (or per segment of a long one) to Dask, follows them as they
finish and appends each video's record to the manifest as soon as it has one;
a video redone with other outputs (``--no-video``, another ``--format``) then
loses the outputs its earlier record lists and the new one does not
(:func:`~fastdet.batch.outputs.remove_replaced`).
A failed task fails its own video only.  Dask re-runs a task whose worker
died (``distributed.scheduler.allowed-failures`` times) and one that raised
an unexpected error (``retries``).  Ctrl-C cancels what is left; every record
written so far stays, so the same command continues from there.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import time
import uuid
from datetime import datetime, timezone
from pathlib import Path

from distributed import as_completed

from .._version import __version__
from ..errors import InputError
from ..video.source import VideoSource
from .boundary import IdMap, compare
from .inputs import display_name
from .manifest import Manifest, input_fingerprint, is_up_to_date
from .outputs import (LOCK_NAME, OutputPaths, output_paths, parts_folder, remove_leftovers,
                      remove_replaced)
from .progress import BatchProgress
from .segments import parse_segment, plan_segments, segment_frames, warmup_frames
from .split_search import replays_from_hits
from .worker import BatchSetup, merge_task, render_task, replay_task, search_task, video_task

#: Extra runs of a task that raised an unexpected exception.
RETRIES = 1
#: Each failed boundary check multiplies the segment's warm-up by this.
WARMUP_GROWTH = 4


class BatchRun:
    """One batch on a Dask client.

    Parameters
    ----------
    client : distributed.Client
    settings : BatchSettings
    out_dir : Path
    force : bool
        Redo videos the manifest says are done.
    segment : str, optional
        ``--segment``: frames (``"500"``) or seconds (``"30s"``) per segment.
    warmup : int, optional
        Frames of warm-up before a segment.  By default segments without
        patch tracking or box snapping are searched in parallel and their
        temporal steps run in one pass (:mod:`fastdet.batch.split_search`),
        and otherwise they warm up for as long as the ``[track]`` settings need
        (:mod:`fastdet.batch.segments`); a number here makes every segment
        warm up that long.  Snapping the boxes' sides to the image
        (``[boxes] snap_sides``, the default) reads the frames' pixels after
        the heat smoothing, so those segments warm up too.

    Attributes
    ----------
    records : list of dict
        After :meth:`run`: the manifest record of every video, in input order.
    skipped : set of str
        Relative paths of the videos that were up to date.
    setup_seconds : float
        Time the workers took to set up (model, kernels) before the first task.
    workers : int
        Workers of the cluster when the batch started.
    """

    def __init__(self, client, settings, out_dir, force=False, segment=None, warmup=None):
        self.client = client
        self.settings = settings
        self.out_dir = Path(out_dir)
        self.force = force
        self.segment = None if segment is None else parse_segment(segment)
        # Without patch tracking the frames to search are known ahead: no
        # warm-up.  The replay feeds the temporal steps hits on blank frames,
        # so only where they read no pixels: no patch tracking, and no box
        # sides snapped to the image's edges ([boxes] snap_sides).
        self.split_search = warmup is None and replays_from_hits(settings)
        if self.split_search:
            self.warmup, self.align = 0, 1
        elif warmup is None:
            self.warmup, self.align = warmup_frames(settings.track_config)
        else:
            self.warmup, self.align = int(warmup), 1
        self.topic = f"fastdet-batch-{uuid.uuid4().hex}"
        self.manifest = Manifest(self.out_dir)
        self.records, self.skipped, self.setup_seconds, self.workers = [], set(), 0.0, 0
        self._futures = {}

    # -- the run -------------------------------------------------------------------
    def run(self, videos, progress=False):
        """Process ``videos`` (:class:`~fastdet.batch.inputs.VideoInput`); see the class notes.

        Parameters
        ----------
        videos : list of VideoInput
        progress : bool
            Draw progress bars (on a terminal).

        Raises
        ------
        KeyboardInterrupt
            After cancelling the remaining tasks; the manifest keeps every
            video finished before.
        """
        with _exclusive(self.out_dir):
            jobs = [job for job in (self._plan(video) for video in videos) if job is not None]
            self.workers = len(self.client.scheduler_info()["workers"])
            bars = BatchProgress(len(jobs), progress)
            self.client.subscribe_topic(self.topic, bars.on_event)
            try:
                if jobs:
                    start = time.perf_counter()
                    self.client.register_plugin(BatchSetup(self.settings), name=self.settings.name)
                    self.setup_seconds = time.perf_counter() - start
                self._follow(jobs, bars)
            finally:
                bars.close()
                with contextlib.suppress(Exception):
                    self.client.unsubscribe_topic(self.topic)
                self.manifest.compact()
        self.records = [self.manifest.get(video.relative) for video in videos]
        return self.records

    def _plan(self, video):
        """The job of one video, or ``None`` when it is up to date (or unreadable: recorded)."""
        outputs = output_paths(video, self.out_dir, self.settings)
        record = self.manifest.get(video.relative)
        try:
            fingerprint = input_fingerprint(video.path, record)
        except OSError as exc:
            self.manifest.add(_failed_record(video, {}, self.settings,
                                             f"cannot read {video.path}: {exc.strerror or exc}"))
            return None
        if not self.force and is_up_to_date(record, fingerprint, self.settings, self.out_dir):
            self.skipped.add(video.relative)
            return None
        for path in outputs.files():
            path.parent.mkdir(parents=True, exist_ok=True)
        segments = self._segments(video)
        if len(segments) > 1:
            return _SegmentedVideo(self, video, outputs, fingerprint, segments)
        return _WholeVideo(self, video, outputs, fingerprint)

    def _segments(self, video):
        if self.segment is None:
            return [(0, None, 0)]
        try:
            with VideoSource(video.path) as reader:
                count, fps = reader.frame_count, reader.fps
        except InputError:
            return [(0, None, 0)]          # its task reports why it cannot be read
        return plan_segments(count, segment_frames(self.segment, fps), self.warmup, self.align)

    def _follow(self, jobs, bars):
        finished = as_completed(with_results=True, raise_errors=False)
        for job in jobs:
            for future in job.start():
                self._track(future, job, finished)
        try:
            for future, result in finished:
                entry = self._futures.pop(future.key, None)
                if entry is None or entry[1].record is not None:
                    continue                 # cancelled: its video failed through another task
                job = entry[1]
                for new in job.advance(future.key, result):
                    self._track(new, job, finished)
                if job.record is not None:
                    self._cancel(job)
                    earlier = self.manifest.get(job.video.relative)
                    self.manifest.add(job.record)
                    remove_leftovers(job.outputs, job.parts)
                    if job.record["status"] == "done":
                        remove_replaced(earlier, self.manifest.records.values(), self.out_dir)
                    bars.video_done()
        except BaseException:
            self.client.cancel([future for future, _ in self._futures.values()])
            raise

    def _track(self, future, job, finished):
        self._futures[future.key] = (future, job)
        finished.add(future)

    def _cancel(self, job):
        stale = [key for key, (_, owner) in self._futures.items() if owner is job]
        self.client.cancel([self._futures.pop(key)[0] for key in stale])

    def submit(self, function, *args, key):
        """Submit a task with a unique key that names its kind first, then its video.

        Dask groups tasks by their key's prefix (``video_task``, ``render_task``, ...):
        one group per kind lets the scheduler learn how long such a task takes
        and spread them over the workers, where a group per video (an unknown
        half-second guess each) left one worker with two videos in a row while
        another idled.  Keys (and progress events) travel as msgpack, which
        refuses the surrogates of a file name that is not UTF-8: they carry the
        video's :func:`~fastdet.batch.inputs.display_name`.  The task's
        arguments are pickled, so its paths keep their bytes.
        """
        key = f"{function.__name__}-{uuid.uuid4().hex[:8]}-{display_name(key)}"
        return self.client.submit(function, *args, key=key, pure=False, retries=RETRIES)

    def record(self, job, tasks, **values):
        """The manifest record of a finished video (``tasks``: the results of its tasks)."""
        record = _base_record(job.video, job.fingerprint, self.settings)
        started = min(t["started"] for t in tasks)
        seconds = max(t["finished"] for t in tasks) - started
        workers = sorted({t["worker"] for t in tasks if "worker" in t})
        record.update(status="done", seconds=round(seconds, 3), workers=workers,
                      outputs=job.outputs.relative_to(self.out_dir), **values)
        record["fps"] = round(record["frames"] / seconds, 2) if seconds > 0 else None
        return record


def _base_record(video, fingerprint, settings):
    return {"relative": video.relative, "input": str(video.path), **fingerprint,
            "model_sha256": settings.model_sha256, "config_sha256": settings.config_sha256,
            "fastdet": __version__,
            "finished": datetime.now(timezone.utc).isoformat(timespec="seconds")}


def _failed_record(video, fingerprint, settings, reason):
    record = _base_record(video, fingerprint, settings)
    record.update(status="failed", reason=reason)
    return record


def _reason(result):
    """The one-line reason of a failed task result, or ``None`` when it succeeded."""
    if isinstance(result, BaseException):
        name = type(result).__name__
        if name == "KilledWorker":
            return "the workers running it died repeatedly (out of memory?)"
        return f"{name}: {' '.join(str(result).split())}"
    if result.get("status") == "failed":
        return result["reason"]
    return None


class _WholeVideo:
    """A video processed by one task."""

    parts = None

    def __init__(self, run, video, outputs, fingerprint):
        self.run, self.video, self.outputs, self.fingerprint = run, video, outputs, fingerprint
        self.record = None

    def start(self):
        job = {"input": str(self.video.path), "outputs": self.outputs.as_dict(),
               "topic": self.run.topic, "key": display_name(self.video.relative)}
        return [self.run.submit(video_task, self.run.settings.name, job, key=self.video.key)]

    def advance(self, key, result):
        reason = _reason(result)
        if reason is not None:
            self.record = _failed_record(self.video, self.fingerprint, self.run.settings, reason)
        else:
            self.record = self.run.record(self, [result], frames=result["frames"],
                                          detections=result["boxes"],
                                          vehicles=len(result["track_ids"]), segments=1)
        return []


class _SegmentedVideo:
    """A long video: segments detected in parallel, boundaries checked, drawn, merged.

    Without patch tracking (:mod:`fastdet.batch.split_search`): every
    segment's search (:func:`~fastdet.batch.worker.search_task`), then one
    task runs their hits through one pipeline
    (:func:`~fastdet.batch.worker.replay_task`) into the detections file
    and, for a video output, each segment's jsonl part.  With patch
    tracking: every segment's detections after a warm-up
    (:func:`~fastdet.batch.worker.video_task` into jsonl parts); the
    boundary checks, left to right, redoing a segment with its tracks
    reordered or a longer warm-up when its check fails (a warm-up from frame
    0 is the whole-video run itself).  Then, either way, with a video output:
    each segment's boxes drawn in whole-video ids
    (:func:`~fastdet.batch.worker.render_task`); the merge.
    """

    def __init__(self, run, video, outputs, fingerprint, segments):
        self.run, self.video, self.outputs, self.fingerprint = run, video, outputs, fingerprint
        self.segments = segments
        self.parts = parts_folder(run.out_dir, video)
        self.record = None
        count = len(segments)
        self.results = [None] * count
        self.maps = [None] * count
        self.warm_starts = [warm for _, _, warm in segments]
        self.reordered = [False] * count
        self.redone = 0
        self.tasks = []
        self.rendered = 0
        self._tags = {}

    def _part(self, k, suffix):
        return self.parts / f"segment-{k:04d}{suffix}"

    def start(self):
        self.parts.mkdir(parents=True, exist_ok=True)
        if self.run.split_search:
            return [self._search(k) for k in range(len(self.segments))]
        return [self._detect(k) for k in range(len(self.segments))]

    def _search(self, k):
        start, end, _ = self.segments[k]
        job = {"input": str(self.video.path), "frame_range": (start, end),
               "hits": str(self._part(k, ".hits.npz")), "topic": self.run.topic,
               "key": f"{display_name(self.video.relative)}#{k}"}
        future = self.run.submit(search_task, self.run.settings.name, job,
                                 key=f"{self.video.key}-search{k}")
        self._tags[future.key] = ("search", k)
        return future

    def _replay(self):
        """One task runs every segment's hits through one pipeline, in order."""
        count = len(self.results)
        # The parts are for drawing the boxes; the detections file is written whole here.
        drawn = self.outputs.video is not None
        job = {"hits": [str(self._part(k, ".hits.npz")) for k in range(count)],
               "detections": [str(self._part(k, ".jsonl")) if drawn else None
                              for k in range(count)],
               "whole": self.outputs.detections and str(self.outputs.detections)}
        future = self.run.submit(replay_task, self.run.settings.name, job,
                                 key=f"{self.video.key}-replay")
        self._tags[future.key] = ("replay", None)
        return future

    def _searched(self):
        """Every segment searched: drop those past the video's real end, then replay."""
        for k, result in enumerate(self.results):
            if result["frames"] == 0:          # the header promised more frames than there are
                self._drop_from(k)
                break
            start, end, _ = self.segments[k]
            if end is not None and result["frames"] < end - start:
                self._drop_from(k + 1)         # the video cannot be read past here
                break
        if not self.results:
            self.record = _failed_record(self.video, self.fingerprint, self.run.settings,
                                         f"{self.video.path}: no frame could be read")
            return []
        return [self._replay()]

    def _replayed(self, result):
        for k, segment in enumerate(result["segments"]):
            self.results[k] = dict(self.results[k], **segment)
        self.maps = [IdMap.identity()] * len(self.results)
        if self.outputs.video is None:
            return self._finish()
        return [self._render(k) for k in range(len(self.segments))]

    def _detect(self, k, order=None):
        start, end, _ = self.segments[k]
        job = {"input": str(self.video.path),
               "outputs": OutputPaths(None, self._part(k, ".jsonl"), None).as_dict(),
               "frame_range": (start, end), "warmup": start - self.warm_starts[k],
               "format": "jsonl", "track_order": order, "topic": self.run.topic,
               "key": f"{display_name(self.video.relative)}#{k}"}
        future = self.run.submit(video_task, self.run.settings.name, job,
                                 key=f"{self.video.key}-segment{k}")
        self._tags[future.key] = ("detect", k)
        return future

    def advance(self, key, result):
        phase, k = self._tags.pop(key)
        reason = _reason(result)
        if reason is not None:
            self.record = _failed_record(self.video, self.fingerprint, self.run.settings, reason)
            return []
        self.tasks.append(result)
        if phase == "search":
            self.results[k] = result
            return self._searched() if all(r is not None for r in self.results) else []
        if phase == "replay":
            return self._replayed(result)
        if phase == "detect":
            self.results[k] = result
            return self._check() if all(r is not None for r in self.results) else []
        if phase == "render":
            self.rendered += 1
            return [self._merge()] if self.rendered == len(self.segments) else []
        return self._finish()

    def _check(self):
        """Certify the boundaries left to right; redo the first segment that fails."""
        config = self.run.settings.detector_config
        for k in range(len(self.results)):
            if k >= len(self.results):         # segments after an early end were dropped
                break
            result = self.results[k]
            if self.maps[k] is not None:
                continue
            if result["frames"] == 0:          # the header promised more frames than there are
                self._drop_from(k)
                break
            start, end, _ = self.segments[k]
            if end is not None and result["frames"] < end - start:
                # The video cannot be read past here: the whole-video run stops here too.
                self._drop_from(k + 1)
            if self.warm_starts[k] == 0:       # read from frame 0: the whole-video run itself
                self.maps[k] = IdMap.identity()
                continue
            before = self.results[k - 1]
            floor = min(r["heat_floor"] for r in self.results[k:])
            verdict = compare(before["end_state"], result["start_state"], config.heat.threshold,
                              floor)
            if verdict.exact:
                self.maps[k] = IdMap.across(*self.maps[k - 1].end_ids(before["end_state"]),
                                            result["start_state"])
                continue
            return [self._redo(k, verdict)]
        if self.outputs.video is None:
            return [self._merge()]
        return [self._render(k) for k in range(len(self.segments))]

    def _redo(self, k, verdict):
        self.redone += 1
        self.results[k] = None
        for j in range(k, len(self.maps)):
            self.maps[j] = None
        if verdict.order is not None and not self.reordered[k]:
            self.reordered[k] = True
            return self._detect(k, order=verdict.order)
        start = self.segments[k][0]
        longer = max(start - self.warm_starts[k], 1) * WARMUP_GROWTH
        self.warm_starts[k] = max(0, start - longer) // self.run.align * self.run.align
        self.reordered[k] = False
        return self._detect(k)

    def _drop_from(self, k):
        for name in ("segments", "results", "maps", "warm_starts"):
            setattr(self, name, getattr(self, name)[:k])

    def _render(self, k):
        start, end, _ = self.segments[k]
        job = {"input": str(self.video.path), "frame_range": (start, end),
               "detections": str(self._part(k, ".jsonl")), "ids": self.maps[k].to_dict(),
               "video": str(self._part(k, ".mp4")),
               "thumbnail": (None if k or self.outputs.thumbnail is None
                             else str(self.outputs.thumbnail)),
               "threads": self.run.settings.threads, "encoder": self.run.settings.encoder}
        future = self.run.submit(render_task, job, key=f"{self.video.key}-render{k}")
        self._tags[future.key] = ("render", k)
        return future

    def _merge(self):
        parts = [{"video": str(self._part(k, ".mp4")) if self.outputs.video else None,
                  "detections": str(self._part(k, ".jsonl")), "ids": self.maps[k].to_dict()}
                 for k in range(len(self.segments))]
        outputs = {"video": self.outputs.video and str(self.outputs.video),
                   # Without warm-ups the replay wrote the detections file already.
                   "detections": (str(self.outputs.detections)
                                  if self.outputs.detections and not self.run.split_search
                                  else None)}
        job = {"parts": parts, "outputs": outputs, "format": self.run.settings.detections_format}
        future = self.run.submit(merge_task, job, key=f"{self.video.key}-merge")
        self._tags[future.key] = ("merge", None)
        return future

    def _finish(self):
        vehicles = set()
        for ids, result in zip(self.maps, self.results):
            vehicles.update(ids(t) for t in result["track_ids"])
        self.record = self.run.record(
            self, self.tasks, frames=sum(r["frames"] for r in self.results),
            detections=sum(r["boxes"] for r in self.results), vehicles=len(vehicles),
            segments=len(self.segments), warmup=self.run.warmup, redone=self.redone)
        return []


@contextlib.contextmanager
def _exclusive(out_dir):
    """Hold ``DIR/.fastdet-batch.lock`` so two batches never write one folder at once.

    The lock is ``flock``'s, which the system releases when its holder dies,
    and the file is removed at the end while still locked.  A batch that opened
    the file just before then locks a file gone from the folder, which would
    exclude nobody: it sees that and opens the lock anew.  A file left behind
    by a killed batch is unlocked, and harmless.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / LOCK_NAME
    while True:
        handle = open(path, "a")
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.close()
            raise InputError(f"another fastdet batch is writing to {out_dir}") from None
        try:
            if os.path.samestat(os.fstat(handle.fileno()), os.stat(path)):
                break
        except FileNotFoundError:
            pass
        handle.close()
    try:
        yield
    finally:
        with contextlib.suppress(OSError):
            path.unlink()
        handle.close()
