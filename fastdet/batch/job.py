"""The per-video job: one video, or one segment of it, through the pipeline to its outputs.

:func:`process_one` is the only place where the batch layer runs the video
layer (``VideoSource`` -> ``VideoPipeline`` -> ``VideoSink`` /
``DetectionWriter``), one frame after the other on the task's thread: a
batch's parallelism is its workers.  It needs what ``process_video`` does not
offer: the temporal state right after the warm-up and at the segment's end,
the smallest heat of every frame and digests of the boundary frames, which
the boundary check compares.

:func:`render_one` draws a segment's boxes, in whole-video track ids, into
its part of the annotated video: a segment cannot draw them while it runs,
because its vehicles' whole-video ids are only known once the boundary before
it is checked.
"""

from __future__ import annotations

import contextlib
import time

import cv2

from ..errors import InputError
from ..files.images import write_image
from ..kernels.reduce import smallest_positive
from ..video.detection_files import DetectionWriter
from ..video.frame_arrays import FrameConverter
from ..video.horizon import resolve_video_horizon
from ..video.pipeline import VideoPipeline
from ..video.sink import VideoSink
from ..video.source import VideoSource
from ..viz.draw import draw_detections_inplace
from .merge import read_part
from .settings import DEFAULT_ENCODER
from .state import frame_digest, pipeline_state, reorder_tracks

#: Width of the thumbnails on the report page.
THUMBNAIL_WIDTH = 320
#: Seconds between two progress reports of a job.
PROGRESS_INTERVAL = 0.5
#: Marks the end of the frames (``None`` is a frame that was not converted).
_END = object()


class _HeatWatch:
    """The detector, noting the smallest positive heat of every frame (see ``boundary``)."""

    def __init__(self, detector):
        self._detector = detector
        self.floor = float("inf")

    def __getattr__(self, name):
        return getattr(self._detector, name)

    def heat_region(self, hits, frame_size):
        heat, origin = self._detector.heat_region(hits, frame_size)
        if heat.size:
            self.floor = min(self.floor, float(smallest_positive(heat)))
        return heat, origin


class _Frames:
    """The reader's frames, numbered, converted only as far as the pipeline looks at them.

    Frames the pipeline does not look at are decoded but not converted
    (``None``); the others are converted whole when the video is drawn, else
    only the rows the detector searches (:meth:`VideoPipeline.rows_read`).
    The frames at ``guards``, the last before each boundary, are always
    converted whole: the boundary check compares their digests.
    """

    def __init__(self, reader, pipeline, convert_all, guards):
        self.index = reader.start
        self.digests = {}
        self._pipeline = pipeline
        self._guards = guards
        self._convert_all = convert_all
        self._rows = None if convert_all else pipeline.rows_read(reader.size)
        self._converter = FrameConverter()
        self._frames = reader.decoded_frames(None if convert_all else
                                             _needed_frames(pipeline, reader.start, guards))

    def __iter__(self):
        return self

    def __next__(self):
        frame = next(self._frames)
        index = self.index
        self.index += 1
        if frame is None:   # left undecoded: neither searched nor guarded
            return None
        if index in self._guards:
            bgr = self._converter.to_bgr(frame)
            self.digests[index] = frame_digest(bgr)
            return bgr
        if self._convert_all or self._pipeline.wants_frame:
            return self._converter.to_bgr(frame, self._rows)
        return None

    def last(self):
        """``(index, digest)`` of the last frame read (digest ``None`` unless guarded)."""
        return self.index - 1, self.digests.get(self.index - 1)


def _needed_frames(pipeline, first, guards):
    """``needed(index)``: the frames the pipeline searches from ``first`` on, and the
    guarded ones; ``None`` when it looks at every frame or cannot say ahead which."""
    searched = pipeline.frames_needed(first)
    if searched is None:
        return None
    return lambda index: index in guards or searched(index)


class ThrottledProgress:
    """Calls ``callback(frames_done)`` at most twice a second (each call is a Dask event)."""

    def __init__(self, callback):
        self._callback = callback
        self._last = time.monotonic()

    def update(self, done):
        now = time.monotonic()
        if now - self._last >= PROGRESS_INTERVAL:
            self._last = now
            self._callback(done)


class _ThumbnailTap:
    """Passes frames on to the video writer and keeps a small copy of one of them."""

    def __init__(self, writer, at_frame):
        self._writer = writer
        self._at = at_frame
        self.thumbnail = None

    def write(self, frame):
        if self._writer.frames == self._at or self.thumbnail is None:
            height = round(frame.shape[0] * THUMBNAIL_WIDTH / frame.shape[1])
            self.thumbnail = cv2.resize(frame, (THUMBNAIL_WIDTH, max(height, 1)),
                                        interpolation=cv2.INTER_AREA)
        self._writer.write(frame)


def warm_up(detector, track_config, frame):
    """Load (or compile) every kernel a video job calls: the pipeline's warm-up, through
    the heat watch the jobs detect with (see :meth:`VideoPipeline.warm_up`).

    An ``"auto"`` horizon is searched at the default until a video's job
    resolves its own: a frame of noise shows none.
    """
    if detector.auto_horizon and detector.config.search.auto_horizon:
        detector.resolve_horizon([])
    VideoPipeline(_HeatWatch(detector), track_config).warm_up(frame)


def process_one(input_path, outputs, options, frame_range=None, warmup_frames=0, *,
                detector, detections_format=None, track_order=None, callback=None):
    """Process one video, or the frames ``frame_range`` of it, into ``outputs``.

    Parameters
    ----------
    input_path : str or Path
    outputs : fastdet.batch.outputs.OutputPaths
        Files to write (``None`` entries are not written); each appears
        under its name only when complete.
    options : fastdet.batch.settings.BatchSettings
        The track configuration and the detections format.
    frame_range : tuple of (int, int or None), optional
        ``(start, end)``: frames ``start`` to ``end - 1`` (``None``: to the
        video's end); the whole video by default.
    warmup_frames : int
        Frames before ``start`` run through the pipeline first, their results
        discarded, so that the temporal state at ``start`` matches the
        whole-video run's (checked by :mod:`fastdet.batch.boundary`).
    detector : fastdet.Detector
        The worker's detector (kernels loaded, model loaded once).
    detections_format : str, optional
        Overrides ``options.detections_format`` (segments write jsonl).
    track_order : list of int, optional
        Permutation of the track table applied after the warm-up.
    callback : callable, optional
        Called now and then with the number of frames written so far.

    Returns
    -------
    dict
        ``frames``, ``boxes``, ``track_ids`` (sorted), ``seconds`` (wall,
        warm-up included), ``warmup_seconds``, ``fps`` and ``size`` of the
        video, ``heat_floor``, the pipeline ``start_state`` and ``end_state``
        (:func:`fastdet.batch.state.pipeline_state`; ``None`` without a
        ``frame_range``), and ``started`` /
        ``finished`` (Unix times).  A segment that lies past the video's end
        gives ``frames`` 0 and no states.

    Raises
    ------
    InputError
        When the video cannot be read (missing, corrupt, no frames) or an
        output cannot be written.
    """
    started = time.time()
    clock = time.perf_counter()
    start, end = frame_range or (0, None)
    warm_start = max(start - int(warmup_frames), 0)
    try:
        # The worker's cores are planned (cluster.plan_layout): FFmpeg's own
        # default, a decoding thread per core in every worker, would oversubscribe them.
        reader = VideoSource(input_path, warm_start, end, threads=options.threads)
    except InputError:
        if warm_start == 0:
            raise
        VideoSource(input_path).close()   # a readable video: the segment is past its end
        return _empty_result(started)
    watch = _HeatWatch(detector)
    pipeline = VideoPipeline(watch, options.track_config)
    with contextlib.ExitStack() as stack:
        stack.enter_context(reader)
        # Every segment of a video resolves the same horizon: from the file's start.
        resolve_video_horizon(detector, reader)
        guards = {start - 1} | ({end - 1} if end is not None else set())
        frames = _Frames(reader, pipeline, outputs.video is not None, guards)
        for _ in range(start - warm_start):
            frame = next(frames, _END)
            if frame is _END:                  # the video ends before the segment starts
                return _empty_result(started)
            pipeline.process(frame)
        if track_order is not None:
            reorder_tracks(pipeline, track_order)
        # Only segments have boundaries to check.
        snapshot = pipeline_state if frame_range is not None else (lambda *_: None)
        start_state = snapshot(pipeline, frames.last() if start > 0 else None)
        warmup_seconds = time.perf_counter() - clock
        writer = det_out = tap = None
        if outputs.video is not None:
            writer = stack.enter_context(VideoSink(outputs.video, reader.fps, reader.size,
                                                   options.codec, options.crf, options.preset,
                                                   threads=options.threads))
            expected = reader.expected_frames
            middle = 0 if expected is None else max(expected - (start - warm_start), 0) // 2
            tap = _ThumbnailTap(writer, middle)
        if outputs.detections is not None:
            det_out = stack.enter_context(
                DetectionWriter(outputs.detections, detections_format or options.detections_format))
        progress = ThrottledProgress(callback) if callback is not None else None
        done = boxes = 0
        track_ids = set()
        try:
            for frame in frames:
                detections = pipeline.process(frame)
                if tap is not None:
                    draw_detections_inplace(frame, detections)
                    tap.write(frame)
                if det_out is not None:
                    det_out.write(start + done, detections)
                done += 1
                boxes += len(detections)
                track_ids.update(detections.track_id.tolist())
                if progress is not None:
                    progress.update(done)
        except KeyboardInterrupt:
            # `fastdet run` keeps what an interrupted run wrote; a batch redoes the video.
            for staged in (writer, det_out):
                if staged is not None:
                    staged.discard()
            raise
        if done == 0:
            return _empty_result(started)
        end_state = snapshot(pipeline, frames.last())
    if outputs.thumbnail is not None and tap is not None and tap.thumbnail is not None:
        write_image(outputs.thumbnail, tap.thumbnail)
    if callback is not None:
        callback(done)
    return {"frames": done, "boxes": boxes, "track_ids": sorted(track_ids),
            "seconds": time.perf_counter() - clock, "warmup_seconds": warmup_seconds,
            "fps": reader.fps, "size": list(reader.size), "heat_floor": watch.floor,
            "start_state": start_state, "end_state": end_state, "started": started,
            "finished": time.time()}


def _empty_result(started):
    return {"frames": 0, "boxes": 0, "track_ids": [], "seconds": 0.0, "warmup_seconds": 0.0,
            "fps": None, "size": None, "heat_floor": float("inf"), "start_state": None,
            "end_state": None, "started": started, "finished": time.time()}


def render_one(input_path, frame_range, detections_part, ids, outputs, threads=1,
               encoder=DEFAULT_ENCODER):
    """Draw a segment's detections into its part of the annotated video.

    Parameters
    ----------
    input_path : str or Path
    frame_range : tuple of (int, int or None)
        The segment's frames.
    detections_part : Path
        The segment's jsonl detections (:func:`process_one` wrote them).
    ids : fastdet.batch.boundary.IdMap
        Its track ids -> whole-video ids.
    outputs : OutputPaths
        ``video`` (the part to write) and optionally ``thumbnail``.
    threads : int
        Decoder and encoder threads (the task's share of the worker's cores).
    encoder : sequence of (str, int or None, str or None)
        Codec, crf and preset (``BatchSettings.encoder``).

    Returns
    -------
    int
        Frames written.
    """
    start, end = frame_range
    with contextlib.ExitStack() as stack:
        reader = stack.enter_context(VideoSource(input_path, start, end, threads=threads))
        codec, crf, preset = encoder
        writer = stack.enter_context(VideoSink(outputs.video, reader.fps, reader.size,
                                               codec, crf, preset, threads=threads))
        expected = reader.expected_frames
        tap = _ThumbnailTap(writer, 0 if expected is None else expected // 2)
        frames = iter(reader)
        for index, detections in read_part(detections_part, ids):
            frame = next(frames, None)
            if frame is None or index != start + writer.frames:
                raise InputError(f"{input_path}: frame {index} of the segment's detections "
                                 "has no frame in the video")
            draw_detections_inplace(frame, detections)
            tap.write(frame)
        written = writer.frames
    if outputs.thumbnail is not None and tap.thumbnail is not None:
        write_image(outputs.thumbnail, tap.thumbnail)
    return written
