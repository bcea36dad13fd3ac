"""One video through :class:`~fastdet.video.pipeline.VideoPipeline` to its outputs.

:func:`stream` pulls frames from a reader, runs the temporal pipeline on
each, draws the boxes into the annotated video and writes the detections
file, timing every stage; ``fastdet run`` is a thin layer over it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..detector.scoring import STAGES
from ..viz.draw import debug_frame, draw_detections_inplace

#: Marks the end of the frame stream (``None`` is a frame that was not converted).
_END = object()

#: Stages of the per-frame time split, in pipeline order.
RUN_STAGES = ("decode", "detect", "track", "draw", "encode", "write")


@dataclass
class RunStats:
    """What a run did, for its summary line.

    ``seconds`` sums the wall time of each of ``RUN_STAGES`` over the run.
    With a background encoder, ``encode`` is only the time the loop waited
    to hand frames over; the encoding itself overlaps the other stages.
    """

    frames: int = 0
    boxes: int = 0
    track_ids: set = field(default_factory=set)
    seconds: dict = field(default_factory=lambda: dict.fromkeys(RUN_STAGES, 0.0))
    wall: float = 0.0
    full_searches: int = 0
    interrupted: bool = False
    #: Seconds spent loading (or compiling) the kernels before the first frame; not in ``wall``.
    warmup: float = 0.0

    def summary(self, outputs):
        """The one-line report printed at the end of a run."""
        fps = self.frames / self.wall if self.wall > 0 else 0.0
        per_frame = ", ".join(f"{stage} {self.seconds[stage] / max(self.frames, 1) * 1e3:.1f}"
                              for stage in RUN_STAGES)
        head = "interrupted after " if self.interrupted else ""
        written = "; wrote " + ", ".join(str(p) for p in outputs) if outputs else ""
        return (f"{head}{self.frames} frames, {self.boxes} detections, {len(self.track_ids)} "
                f"tracks, {self.full_searches} full searches, {fps:.1f} fps; "
                f"ms/frame: {per_frame}; kernels ready in {self.warmup:.1f} s before the "
                f"first frame (not in fps){written}")


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


def stream(reader, pipeline, first_index, video_out=None, det_out=None, progress=None,
           debug_view=False, warmup=0.0):
    """Push every frame of ``reader`` through the pipeline to the outputs.

    Parameters
    ----------
    reader : iterable of ndarray
        Frames in order.
    pipeline : VideoPipeline
    first_index : int
        Index of the first frame in the input video.
    video_out : VideoWriter, optional
        Receives each frame with its boxes drawn.
    det_out : DetectionWriter, optional
        Receives each frame's detections.
    progress : Progress, optional
    debug_view : bool
        Draw the live heat map and per-stage timings into the video frames.
    warmup : float
        Seconds the caller spent loading the kernels first (reported, not timed).

    Returns
    -------
    RunStats
        With ``interrupted`` set when Ctrl-C stopped the run: the interrupt
        is absorbed so the caller can complete the outputs first.
    """
    stats = RunStats(warmup=warmup)
    seconds = stats.seconds
    start = time.perf_counter()
    if video_out is None and hasattr(reader, "frames"):
        # Frames the pipeline does not look at need not be converted.
        frames = reader.frames(skip=lambda: not pipeline.wants_frame)
    else:
        frames = iter(reader)
    try:
        while True:
            t0 = time.perf_counter()
            frame = next(frames, _END)
            t1 = time.perf_counter()
            seconds["decode"] += t1 - t0
            if frame is _END:
                break
            detections = pipeline.process(frame)
            t2 = time.perf_counter()
            if video_out is not None:
                if debug_view:
                    frame = _debug_view(frame, detections, pipeline)
                else:
                    draw_detections_inplace(frame, detections)
                t3 = time.perf_counter()
                video_out.write(frame)
                t4 = time.perf_counter()
                seconds["draw"] += t3 - t2
                seconds["encode"] += t4 - t3
                t2 = t4
            if det_out is not None:
                det_out.write(first_index + stats.frames, detections)
                seconds["write"] += time.perf_counter() - t2
            stats.frames += 1
            stats.boxes += len(detections)
            stats.track_ids.update(detections.track_id.tolist())
            if progress is not None:
                elapsed = time.perf_counter() - start
                progress.update(stats.frames, stats.frames / elapsed if elapsed > 0 else 0.0)
    except KeyboardInterrupt:
        stats.interrupted = True
    stats.wall = time.perf_counter() - start
    seconds["detect"] = pipeline.seconds["detect"]
    seconds["track"] = pipeline.seconds["track"]
    stats.full_searches = pipeline.full_searches
    return stats
