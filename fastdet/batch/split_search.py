"""Segments without patch tracking: each segment's search in parallel, the temporal steps in one pass.

Without patch tracking (``[track] tracking = false``, the default) a
pipeline's frames to search are fixed in advance, every ``every``-th frame
from the first, and a frame's hits (the scoring of every window, nearly all
of the work) depend on that frame alone; everything that carries over from
frame to frame (heat smoothing, boxes, tracks and their ids) is computed from
the hits, in order.  So a long video is processed in two phases:

1. :func:`search_segment`, one task per segment, in parallel: decode the
   segment's frames and save the detector's hits of the searched ones;
2. :func:`replay_segments`, one task: feed every segment's hits, in frame
   order, through one :class:`~fastdet.video.pipeline.VideoPipeline`, and
   write each segment's detections.

The pipeline of phase 2 receives the same hits, in the same order, as the
pipeline of a whole-video run: its detections, track ids included, are the
whole-video run's by construction, with no warm-up and nothing to check at
the boundaries.  Phase 2 costs the temporal steps alone (about a tenth of a
frame's work).  With patch tracking, whether a frame is searched depends on
the frames before it, and segments warm up instead (:mod:`.segments`); so
they do when the boxes' sides snap to the image (``[boxes] snap_sides``,
read after the heat smoothing, from pixels a replay does not have).
"""

from __future__ import annotations

import contextlib
import time

import numpy as np

from ..detector.scoring import Hits
from ..errors import InputError
from ..files.atomic import atomic_path
from ..video.detection_files import DetectionWriter
from ..video.frame_arrays import FrameConverter
from ..video.pipeline import VideoPipeline
from ..video.source import VideoSource
from .job import ThrottledProgress


def replays_from_hits(settings):
    """Whether a batch with ``settings`` can run its segments this way: its
    temporal steps read no pixels (no patch tracking, and no box sides
    snapped to the frame's edges), so that hits on blank frames replay them,
    and its horizon is a number (an ``"auto"`` one is each video's, which
    the segments with a warm-up resolve from the file's start)."""
    return (not settings.track_config.tracking and not settings.detector_config.boxes.snap_sides
            and not settings.detector_config.search.auto_horizon)


def search_segment(input_path, frame_range, hits_path, options, *, detector, callback=None):
    """Phase 1: the detector's hits of a segment's searched frames, saved to ``hits_path``.

    Parameters
    ----------
    input_path : str or Path
    frame_range : tuple of (int, int or None)
        ``(start, end)``: frames ``start`` to ``end - 1`` (``None``: to the end).
    hits_path : Path
        The ``.npz`` file to write (atomically).
    options : fastdet.batch.settings.BatchSettings
        Its track configuration (without patch tracking) and decoder threads.
    detector : fastdet.Detector
        The worker's detector.
    callback : callable, optional
        Called now and then with the number of frames read so far.

    Returns
    -------
    dict
        ``frames`` read, the video's ``fps`` and ``size``, ``seconds``.

    Raises
    ------
    InputError
        When the video cannot be read or the file cannot be written.
    """
    clock = time.perf_counter()
    track_config = options.track_config
    if track_config.tracking:
        raise ValueError("segments with patch tracking warm up instead (fastdet.batch.segments)")
    start, end = frame_range
    index, boxes, scores, scales, windows = [], [], [], [], []
    converter = FrameConverter()
    progress = ThrottledProgress(callback) if callback is not None else None
    with VideoSource(input_path, start, end, threads=options.threads) as reader:
        pipeline = VideoPipeline(detector, track_config)
        rows = pipeline.rows_read(reader.size)
        # The whole video's search schedule (it starts at frame 0); None: every frame.
        needed = pipeline.frames_needed(0)
        frames = reader.decoded_frames(needed)
        done = 0
        for done, frame in enumerate(frames, 1):
            at = start + done - 1
            if frame is None or (needed is not None and not needed(at)):
                continue
            hits = detector.hits(converter.to_bgr(frame, rows))
            index.append(at)
            windows.append(hits.windows_scored)
            boxes.append(hits.boxes)
            scores.append(hits.scores)
            scales.append(hits.scale_index)
            if progress is not None:
                progress.update(done)
        fps, size = reader.fps, list(reader.size)
    if callback is not None:
        callback(done)
    with atomic_path(hits_path) as temporary:
        with open(temporary, "wb") as file:
            np.savez(file, start=start, frames=done, size=np.asarray(size, np.int64),
                     index=np.asarray(index, np.int64), windows=np.asarray(windows, np.int64),
                     counts=np.asarray([len(b) for b in boxes], np.int64),
                     boxes=_joined(boxes, np.int32, (0, 4)), scores=_joined(scores, np.float32),
                     scale_index=_joined(scales, np.int64))
    return {"frames": done, "fps": fps, "size": size, "seconds": time.perf_counter() - clock}


def _joined(arrays, dtype, empty_shape=(0,)):
    return np.concatenate(arrays).astype(dtype, copy=False) if arrays else np.zeros(empty_shape,
                                                                                    dtype)


def replay_segments(hits_paths, detections_paths, options, *, detector, whole=None):
    """Phase 2: every segment's hits through one pipeline, in frame order.

    Parameters
    ----------
    hits_paths : sequence of Path
        :func:`search_segment`'s files, in the segments' order.
    detections_paths : sequence of Path or None
        Each segment's detections, written as jsonl (frame indices of the
        whole video, track ids of the whole video), for drawing them; ``None``:
        not written.
    options : fastdet.batch.settings.BatchSettings
        Its track configuration and detections format.
    detector : fastdet.Detector
        The worker's detector (only its heat and box steps run).
    whole : Path, optional
        The video's detections file, in ``options.detections_format``: the
        same file a whole-video run writes (written once complete).

    Returns
    -------
    list of dict
        Per segment: ``frames``, ``boxes`` and ``track_ids`` (sorted).

    Raises
    ------
    InputError
        When the segments do not follow each other, or the pipeline would
        search a frame whose hits are missing.
    ValueError
        For ``options`` whose temporal steps read pixels (see
        :func:`replays_from_hits`).
    """
    if not replays_from_hits(options):
        raise ValueError("these settings track patches, snap box sides to the frame or "
                         "estimate the horizon: their segments cannot be replayed from hits")
    pipeline = VideoPipeline(detector, options.track_config)
    results, expected_start, blank = [], 0, None
    with contextlib.ExitStack() as outputs:
        everything = (None if whole is None else
                      outputs.enter_context(DetectionWriter(whole, options.detections_format)))
        for hits_path, detections_path in zip(hits_paths, detections_paths):
            result, blank = _replay_one(pipeline, hits_path, detections_path, everything,
                                        expected_start, blank)
            results.append(result)
            expected_start += result["frames"]
    return results


def _replay_one(pipeline, hits_path, detections_path, everything, expected_start, blank):
    """One segment of :func:`replay_segments`: its result, and the blank frame of its size."""
    with np.load(hits_path) as part:
        data = {name: part[name] for name in part.files}
    start, frames = int(data["start"]), int(data["frames"])
    if start != expected_start:
        raise InputError(f"{hits_path}: the segment starts at frame {start}, "
                         f"not {expected_start}")
    width, height = (int(v) for v in data["size"])
    if blank is None or blank.shape[:2] != (height, width):
        # The frame a pipeline is given with its hits: without patch
        # tracking or snapping (replays_from_hits) nothing reads its pixels,
        # only its size.
        blank = np.zeros((height, width, 3), np.uint8)
    hits_of = _hits_by_frame(data)
    boxes, track_ids = 0, set()
    with contextlib.ExitStack() as stack:
        writers = [] if everything is None else [everything]
        if detections_path is not None:
            writers.append(stack.enter_context(DetectionWriter(detections_path, "jsonl")))
        for at in range(start, start + frames):
            hits = hits_of.get(at)
            if hits is None and pipeline.wants_frame:
                raise InputError(f"{hits_path}: frame {at} is searched but has no hits")
            detections = pipeline.process(None if hits is None else blank, hits=hits)
            for writer in writers:
                writer.write(at, detections)
            boxes += len(detections)
            track_ids.update(detections.track_id.tolist())
    return {"frames": frames, "boxes": boxes, "track_ids": sorted(track_ids)}, blank


def _hits_by_frame(data):
    """``{frame index: Hits}`` of one segment's saved arrays."""
    ends = np.cumsum(data["counts"])
    begins = ends - data["counts"]
    return {int(at): Hits(data["boxes"][b:e], data["scores"][b:e], data["scale_index"][b:e],
                          int(windows))
            for at, b, e, windows in zip(data["index"], begins, ends, data["windows"])}
