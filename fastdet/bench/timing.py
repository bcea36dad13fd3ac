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
import numba
import numpy as np

from ..detector.scoring import STAGES
from ..video.source import VideoSource

#: Stage names as printed, in pipeline order; "python overhead" is the rest.
STAGE_LABELS = {"resize_convert": "resize+convert", "cells": "cells",
                "blocks_score": "blocks+scores", "colour_maps": "colour maps",
                "heat": "heat", "label": "labelling"}

#: Consecutive frames per pipeline's turn in ``fastdet bench`` (see
#: :func:`time_fastdet_in_turn`).
TURN_FRAMES = 8


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
    # One pipeline alone needs no turns: its frames back to back, as a video.
    return time_fastdet_in_turn([(name, detector)], frames, repeat,
                                turn_frames=max(len(frames), 1))[0]


def time_fastdet_in_turn(named_detectors, frames, repeat=3, also=None,
                         turn_frames=TURN_FRAMES):
    """:func:`time_fastdet` of several detectors, in turns over the same frames.

    Each turn covers ``turn_frames`` consecutive frames: the first detector
    makes one untimed call on the turn's first frame, then its ``repeat``
    timed calls on each of the turn's frames, then the next detector does the
    same, each with its own thread counts set (Numba's and OpenCV's, which
    :class:`~fastdet.detector.detector.Detector` sets process-wide when it is
    made), then ``also`` gets the turn's frame indices.  A slow spell of a
    shared machine then hits all of them alike: timed one after the other, a
    minute apart, two threads came out 0.86x, 2.2x and 1.6x one thread in
    three runs of ``fastdet bench`` on one machine (AMD EPYC Zen 4, 2 vCPUs).
    Turns of several frames time each pipeline as a video runs it, frames
    back to back: on a 2-core Xeon VM a one-thread frame took 0.2-0.45 ms
    longer in each of the first three calls after the process had waited or
    spun for 6 ms, so turns of one frame charge that wake-up to every frame.

    Parameters
    ----------
    named_detectors : sequence of (str, Detector)
    frames : list of ndarray
    repeat : int
    also : callable, optional
        Called with the list of each turn's frame indices after the
        detectors' calls on them (e.g.
        :meth:`~fastdet.bench.peers.OpenCVPeer.time_turn`).
    turn_frames : int
        Consecutive frames per turn (1: every frame a turn of its own).

    Returns
    -------
    list of PipelineResult
        In the order of ``named_detectors``.
    """
    if turn_frames < 1:
        raise ValueError(f"turn_frames must be at least 1, got {turn_frames}")
    timers = [_DetectorTimes(name, detector) for name, detector in named_detectors]
    for timer in timers:
        timer.use_threads()
        timer.detector(frames[0])
    for first in range(0, len(frames), turn_frames):
        turn = range(first, min(first + turn_frames, len(frames)))
        for timer in timers:
            timer.use_threads()
            timer.detector(frames[first])
            for index in turn:
                timer.time_frame(frames[index], repeat)
        if also is not None:
            also(list(turn))
    return [timer.result() for timer in timers]


class _DetectorTimes:
    """What :func:`time_fastdet_in_turn` adds up for one detector."""

    def __init__(self, name, detector):
        self.name, self.detector = name, detector
        self.per_frame = []
        self.stage_totals = dict.fromkeys(STAGES, 0.0)
        self.busy_totals = np.zeros(len(detector.thread_busy))
        self.cpu_totals = np.zeros(len(detector.thread_cpu))
        self.estimates = []
        self.windows = 0
        self.runs = 0

    def use_threads(self):
        numba.set_num_threads(self.detector.threads)
        cv2.setNumThreads(self.detector.threads)

    def time_frame(self, frame, repeat):
        detector = self.detector
        self.use_threads()
        samples = []
        for _ in range(repeat):
            cpu = time.thread_time()
            start = time.perf_counter()
            detector(frame)
            samples.append(time.perf_counter() - start)
            serial = time.thread_time() - cpu - detector.thread_cpu[0]
            self.estimates.append(serial + sum(detector.thread_cpu) / detector.threads)
            for stage in STAGES:
                self.stage_totals[stage] += detector.timings[stage]
            self.busy_totals += detector.thread_busy
            self.cpu_totals += detector.thread_cpu
        self.per_frame.append(statistics.median(samples))
        self.windows += detector.last_windows_scored
        self.runs += repeat

    def result(self):
        frames, runs = len(self.per_frame), self.runs
        stages = {stage: total / runs * 1e3 for stage, total in self.stage_totals.items()}
        return PipelineResult(self.name, self.per_frame, list(range(frames)),
                              self.windows / frames, stages,
                              list(self.busy_totals / runs * 1e3),
                              list(self.cpu_totals / runs * 1e3),
                              statistics.median(self.estimates) * 1e3)


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
