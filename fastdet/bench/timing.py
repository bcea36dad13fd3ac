"""Timing fastdet per frame: frames to time, per-frame medians, speed-ups.

Every pipeline runs on the same decoded frames in the same benchmark run, so
ratios are measured under the same machine load, and every ratio compares
times on the same frames.
"""

from __future__ import annotations

import math
import statistics
import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from ..detector.scoring import STAGES
from ..video.source import VideoSource

#: Stage names as printed, in pipeline order; "python overhead" is the rest.
STAGE_LABELS = {"resize_convert": "resize+convert", "cells": "cells",
                "blocks_score": "blocks+scores", "colour_maps": "colour maps",
                "heat": "heat", "label": "labelling"}


@dataclass
class PipelineResult:
    """Per-frame timings of one pipeline.

    Attributes
    ----------
    name : str
    seconds : list of float
        One latency per timed frame.
    frame_indices : list of int
        Index (into the benchmark's frames) of each timed frame.
    windows_per_frame : float
    stages : dict
        fastdet only: mean milliseconds per stage (``STAGES``) and ``total``.
    thread_busy : list of float
        fastdet only: mean milliseconds each thread worked per frame (the
        calling thread first; see ``Detector.thread_busy``).
    thread_cpu : list of float
        fastdet only: mean CPU milliseconds of that work per thread.
    idle_estimate_ms : float
        fastdet only: the median over calls of the calling thread's CPU
        outside its share plus the threads' work CPU divided by their
        number -- the latency on idle cores, which other processes' load
        does not inflate (see :func:`time_fastdet`).
    """

    name: str
    seconds: list
    frame_indices: list
    windows_per_frame: float
    stages: dict = field(default_factory=dict)
    thread_busy: list = field(default_factory=list)
    thread_cpu: list = field(default_factory=list)
    idle_estimate_ms: float = math.nan

    @property
    def median_ms(self):
        return statistics.median(self.seconds) * 1e3

    @property
    def min_ms(self):
        return min(self.seconds) * 1e3

    @property
    def max_ms(self):
        return max(self.seconds) * 1e3

    def median_ms_on(self, indices):
        """Median latency over the given frames (those this pipeline timed)."""
        by_frame = dict(zip(self.frame_indices, self.seconds, strict=True))
        chosen = [by_frame[i] for i in indices if i in by_frame]
        return statistics.median(chosen) * 1e3 if chosen else math.nan


def speedup(baseline, result):
    """How many times faster ``result`` is than ``baseline``, on the frames both timed.

    Returns
    -------
    float
        ``nan`` when either is missing or they share no frame.
    """
    if baseline is None or result is None:
        return math.nan
    shared = sorted(set(baseline.frame_indices) & set(result.frame_indices))
    if not shared:
        return math.nan
    return baseline.median_ms_on(shared) / result.median_ms_on(shared)


# -- frames -------------------------------------------------------------------
def read_frames(video, count=None, size=None):
    """Decode up to ``count`` frames of a video, optionally resized to ``(w, h)``."""
    frames = []
    with VideoSource(video) as source:
        for frame in source:
            if count is not None and len(frames) >= count:
                break
            frames.append(resize_frame(frame, size))
    return frames


def resize_frame(frame, size):
    """``frame`` at ``(width, height)`` (area averaging down, bilinear up)."""
    if size is None or (frame.shape[1], frame.shape[0]) == tuple(size):
        return frame
    shrinking = size[0] * size[1] < frame.shape[0] * frame.shape[1]
    return cv2.resize(frame, tuple(size),
                      interpolation=cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR)


def spread_indices(count, wanted):
    """Up to ``wanted`` frame indices spread evenly over ``count`` frames."""
    if wanted <= 0 or count == 0:
        return []
    return sorted({int(round(i)) for i in np.linspace(0, count - 1, min(wanted, count))})


# -- fastdet ------------------------------------------------------------------
def time_fastdet(detector, frames, repeat=3, name="fastdet"):
    """Per-frame latency of a Detector: the median of ``repeat`` calls per frame.

    The first frame is detected once untimed, so compilation, cache loading
    and buffer allocation are not counted.  Besides wall-clock time, each
    call's CPU time is taken: the calling thread's (``time.thread_time``)
    outside its share of the frame is the serial part, and the serial part
    plus the threads' work divided among them estimates the latency on
    idle cores (it assumes the threads, which take tasks as they finish
    them, would split the work evenly).
    """
    detector(frames[0])
    per_frame = []
    stage_totals = dict.fromkeys(STAGES, 0.0)
    busy_totals = np.zeros(len(detector.thread_busy))
    cpu_totals = np.zeros(len(detector.thread_cpu))
    estimates = []
    windows = 0
    for frame in frames:
        samples = []
        for _ in range(repeat):
            cpu = time.thread_time()
            start = time.perf_counter()
            detector(frame)
            samples.append(time.perf_counter() - start)
            serial = time.thread_time() - cpu - detector.thread_cpu[0]
            estimates.append(serial + sum(detector.thread_cpu) / detector.threads)
            for stage in STAGES:
                stage_totals[stage] += detector.timings[stage]
            busy_totals += detector.thread_busy
            cpu_totals += detector.thread_cpu
        per_frame.append(statistics.median(samples))
        windows += detector.last_windows_scored
    runs = len(frames) * repeat
    stages = {stage: total / runs * 1e3 for stage, total in stage_totals.items()}
    return PipelineResult(name, per_frame, list(range(len(frames))), windows / len(frames),
                          stages, list(busy_totals / runs * 1e3), list(cpu_totals / runs * 1e3),
                          statistics.median(estimates) * 1e3)


def fastdet_name(threads):
    return f"fastdet {threads} thread" + ("s" if threads > 1 else "")


def time_callable(name, detect, frames, indices, windows_per_frame):
    """Per-frame latency of a slow peer: one call per frame after one warm-up call."""
    detect(frames[indices[0]])
    seconds = []
    for index in indices:
        start = time.perf_counter()
        detect(frames[index])
        seconds.append(time.perf_counter() - start)
    return PipelineResult(name, seconds, list(indices), windows_per_frame)
