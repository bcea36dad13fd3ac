"""``fastdet bench``: per-frame latency of fastdet and its peers, side by side.

Every pipeline runs on the same decoded frames in the same benchmark run, so
ratios are measured under the same machine load, and every ratio compares
times on the same frames: the slow reference is timed on a subsample of the
frames and compared with fastdet's times on exactly those frames.

Peers:

* ``reference``: the seed-faithful reference pipeline
  (``benchmarks/reference.py`` of the checkout; scikit-image HOG and one
  scikit-learn call per window), same model, same windows;
* ``opencv``: OpenCV's ``HOGDescriptor`` with a linear SVM trained on its own
  grey HOG features, run by ``benchmarks/opencv_peer/peer.py`` in its own
  virtual environment (OpenCV 5, which fastdet uses, has no
  ``HOGDescriptor``); see :func:`run_opencv_peer`.
"""

from __future__ import annotations

import importlib.util
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from .detect import STAGES, Detector
from .errors import InputError

#: Stage names as printed, in pipeline order; "python overhead" is the rest.
STAGE_LABELS = {"resize_convert": "resize+convert", "cells": "cells",
                "blocks_score": "blocks+score", "colour_score": "colour score",
                "heat": "heat", "label": "labelling"}

#: Environment variable naming the OpenCV peer's virtual environment.
OPENCV_PEER_ENV = "FASTDET_OPENCV_PEER"

#: ``winStride`` of the OpenCV peer's native ``detectMultiScale`` search, in
#: pixels of the 64-pixel window (75% overlap: the densest overlap fastdet's
#: default scales use).
NATIVE_WIN_STRIDE = 16


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
    """

    name: str
    seconds: list
    frame_indices: list
    windows_per_frame: float
    stages: dict = field(default_factory=dict)

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
    capture = cv2.VideoCapture(str(video))
    if not capture.isOpened():
        raise InputError(f"cannot open video {video}")
    frames = []
    try:
        while count is None or len(frames) < count:
            ok, frame = capture.read()
            if not ok:
                break
            frames.append(resize_frame(frame, size))
    finally:
        capture.release()
    if not frames:
        raise InputError(f"no frames could be read from {video}")
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
    and buffer allocation are not counted.
    """
    detector(frames[0])
    per_frame = []
    stage_totals = dict.fromkeys(STAGES, 0.0)
    windows = 0
    for frame in frames:
        samples = []
        for _ in range(repeat):
            start = time.perf_counter()
            detector(frame)
            samples.append(time.perf_counter() - start)
            for stage in STAGES:
                stage_totals[stage] += detector.timings[stage]
        per_frame.append(statistics.median(samples))
        windows += detector.last_windows_scored
    runs = len(frames) * repeat
    stages = {stage: total / runs * 1e3 for stage, total in stage_totals.items()}
    return PipelineResult(name, per_frame, list(range(len(frames))), windows / len(frames),
                          stages)


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


# -- peers: where they live ---------------------------------------------------
def benchmarks_dir():
    """The checkout's ``benchmarks/`` folder (peers live there), or None."""
    for root in (Path.cwd(), Path(__file__).resolve().parent.parent):
        if (root / "benchmarks" / "reference.py").is_file():
            return root / "benchmarks"
    return None


def load_reference_module():
    """The seed-faithful reference from the checkout's ``benchmarks/``, or None."""
    folder = benchmarks_dir()
    if folder is None:
        return None
    spec = importlib.util.spec_from_file_location("fastdet_bench_reference",
                                                  folder / "reference.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def opencv_peer_python():
    """Python of the OpenCV peer's virtual environment, or None if not set up.

    The environment is ``$FASTDET_OPENCV_PEER`` (default
    ``~/.cache/fastdet/opencv-peer``), made by
    ``benchmarks/opencv_peer/setup.sh``.
    """
    cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    venv = Path(os.environ.get(OPENCV_PEER_ENV, cache / "fastdet" / "opencv-peer"))
    python = venv / "bin" / "python"
    return python if python.is_file() else None


def cache_dir():
    """Where benchmarks keep data-derived artefacts (never in the checkout)."""
    cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    return cache / "fastdet"


# -- OpenCV peer ---------------------------------------------------------------
def native_search(plans):
    """The OpenCV peer's ``detectMultiScale`` settings comparable to fastdet's plans.

    The band every scale searches is upscaled so that the smallest fastdet
    window becomes OpenCV's 64-pixel window; the pyramid has one level per
    fastdet scale, spaced geometrically from the smallest to the largest
    window side, with a fixed ``winStride`` of ``NATIVE_WIN_STRIDE`` pixels.
    """
    sides = [(plan.roi[2] - plan.roi[0]) * 64.0 / plan.scaled_size[0] for plan in plans]
    smallest, largest = min(sides), max(sides)
    levels = len(plans)
    return {
        "region": [min(p.roi[0] for p in plans), min(p.roi[1] for p in plans),
                   max(p.roi[2] for p in plans), max(p.roi[3] for p in plans)],
        "upscale": 64.0 / smallest,
        "scale": (largest / smallest) ** (1.0 / (levels - 1)) if levels > 1 else 1.05,
        "nlevels": levels,
        "win_stride": NATIVE_WIN_STRIDE,
    }


def opencv_peer_job(plans, threads=(1,), repeat=3, data=None, train_stride=1):
    """The job description :func:`run_opencv_peer` hands the peer (without frames)."""
    from .shared_data import data_dir

    return {
        "data_dir": str(Path(data or data_dir()).resolve()),
        "cache_dir": str(cache_dir() / "opencv_peer"),
        "threads": [int(t) for t in threads],
        "repeat": int(repeat),
        "train_stride": int(train_stride),
        "hit_threshold": 0.0,
        "plans": [{"roi": list(plan.roi), "scaled_size": list(plan.scaled_size),
                   "step_px": plan.step_cells * 8} for plan in plans],
        "native": native_search(plans),
    }


def run_opencv_peer(frames, plans, threads=(1,), repeat=3, data=None, timeout=1800,
                    peer_script=None):
    """Time OpenCV's HOGDescriptor on ``frames`` in its own environment.

    Parameters
    ----------
    frames : list of ndarray
        BGR frames, all of one size (the ones fastdet is timed on).
    plans : tuple of ScalePlan
        fastdet's plans for that size (pixels per cell must be 8, OpenCV's cell).
    threads : sequence of int
        ``cv2.setNumThreads`` values to time.
    repeat : int
        Timed passes per frame (the median is kept).
    data : path, optional
        Data set for the peer's SVM (default: the shared data).
    timeout : float
        Seconds the peer may take (training its SVM included, on a cold cache).
    peer_script : path, optional
        ``peer.py`` (default: the checkout's ``benchmarks/opencv_peer/peer.py``).

    Returns
    -------
    results : list of PipelineResult
        ``opencv same windows, T thread(s)`` and ``opencv native, ...``.
    info : dict
        The peer's report: OpenCV version, training figures.

    Raises
    ------
    InputError
        When the peer environment is missing or the peer fails.
    """
    python = opencv_peer_python()
    if peer_script is None and benchmarks_dir() is not None:
        peer_script = benchmarks_dir() / "opencv_peer" / "peer.py"
    if python is None or peer_script is None:
        raise InputError("OpenCV peer not set up: run `bash benchmarks/opencv_peer/setup.sh` "
                         f"from the checkout (or set {OPENCV_PEER_ENV} to its environment)")
    job = opencv_peer_job(plans, threads, repeat, data)
    with tempfile.TemporaryDirectory(prefix="fastdet-opencv-peer-") as tmp:
        job["frames"] = str(Path(tmp) / "frames.npy")
        np.save(job["frames"], np.stack(frames))
        job_file = Path(tmp) / "job.json"
        job_file.write_text(json.dumps(job))
        completed = subprocess.run([str(python), str(peer_script), str(job_file)],
                                   capture_output=True, text=True, timeout=timeout, cwd=tmp)
    if completed.returncode != 0:
        tail = " ".join(completed.stderr.strip().splitlines()[-3:])
        raise InputError(f"OpenCV peer failed (exit {completed.returncode}): {tail}")
    report = json.loads(completed.stdout.strip().splitlines()[-1])
    results = []
    for entry in report["results"]:
        label = "same windows" if entry["mode"] == "same_windows" else "native multiscale"
        threads_label = f"{entry['threads']} thread" + ("s" if entry["threads"] > 1 else "")
        results.append(PipelineResult(f"opencv {label}, {threads_label}", entry["seconds"],
                                      list(range(len(entry["seconds"]))),
                                      entry["windows_per_frame"]))
    return results, report


# -- the comparison -----------------------------------------------------------
@dataclass
class BenchmarkRun:
    """Everything one ``fastdet bench`` comparison measured."""

    results: list
    frame_count: int
    frame_size: tuple
    plans: tuple
    notes: list = field(default_factory=list)
    opencv: dict | None = None

    def get(self, name):
        return next((r for r in self.results if r.name == name), None)

    @property
    def reference(self):
        return self.get("reference")

    @property
    def opencv_same_windows(self):
        """OpenCV on exactly fastdet's windows with one thread: the ratio's baseline."""
        return self.get("opencv same windows, 1 thread")


def run_benchmark(frames, threads=(1,), repeat=3, reference_frames=5, opencv=True,
                  model=None, config=None, log=print):
    """Time fastdet (per thread count) and its peers on the same frames.

    Parameters
    ----------
    frames : list of ndarray
        Decoded BGR frames of one size.
    threads : sequence of int
        Thread counts to time fastdet with.
    repeat : int
        Timed calls per frame for fastdet and OpenCV (median kept).
    reference_frames : int
        Frames (spread over the video) the slow reference is timed on; 0
        skips it.
    opencv : bool
        Also time the OpenCV peer (skipped with a note when not set up).
    model, config
        As for :class:`~fastdet.detect.Detector` (``None``: bundled model,
        built-in config).
    log : callable
        Receives progress and skip notes.

    Returns
    -------
    BenchmarkRun
    """
    size = (frames[0].shape[1], frames[0].shape[0])
    notes = []
    threads = sorted(set(threads))

    def fastdet_run(count):
        # Detector() sets the process-wide thread count: time it right away.
        detector = Detector(model=model, config=config, threads=count)
        log(f"timing {fastdet_name(detector.threads)} on {len(frames)} frames ...")
        return detector, time_fastdet(detector, frames, repeat, fastdet_name(detector.threads))

    # One thread first, peers next, more threads last: an OpenMP pool keeps
    # spinning for a while after a parallel region and would slow whatever
    # runs right after it on a busy machine.
    detector, first = fastdet_run(threads[0])
    fastdet_results, peer_results = [first], []
    plans = detector.plans(size)
    model_obj, config_obj = detector.model, detector.config
    Detector(model=model_obj, config=config_obj, threads=1)  # peers get one thread too

    if reference_frames:
        reference = load_reference_module()
        if reference is None:
            notes.append("reference skipped: needs the checkout's benchmarks/reference.py "
                         "(run from the checkout)")
        else:
            indices = spread_indices(len(frames), reference_frames)
            log(f"timing the reference on frames {indices} ...")
            peer = reference.ReferenceDetector(model_obj, config_obj)
            peer_results.append(time_callable("reference", peer, frames, indices,
                                              first.windows_per_frame))
    opencv_report = None
    if opencv:
        if model_obj.options.pixels_per_cell != 8:
            notes.append("OpenCV peer skipped: it needs 8-pixel cells")
        else:
            try:
                log("timing the OpenCV HOGDescriptor peer (its own environment) ...")
                opencv_results, opencv_report = run_opencv_peer(frames, plans, threads, repeat)
                peer_results.extend(opencv_results)
            except (InputError, subprocess.TimeoutExpired) as exc:
                notes.append(f"OpenCV peer skipped: {exc}")
    for count in threads[1:]:
        fastdet_results.append(fastdet_run(count)[1])
    results = fastdet_results + peer_results
    for note in notes:
        log(note)
    return BenchmarkRun(results, len(frames), size, plans, notes, opencv_report)


# -- tables ---------------------------------------------------------------------
def _ratio(value):
    if not math.isfinite(value):
        return "n/a"
    # Two significant digits below 1 (the reference is ~0.01x of OpenCV).
    return f"{value:.1f}x" if value >= 1 else f"{value:.2g}x"


def format_table(run):
    """Markdown table: latency, windows and same-frame ratios of every pipeline."""
    reference, opencv = run.reference, run.opencv_same_windows
    lines = ["| pipeline | frames | median ms | min ms | max ms | windows/frame "
             "| x faster than reference | x faster than OpenCV (same windows, 1 thread) |",
             "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for result in run.results:
        lines.append(f"| {result.name} | {len(result.seconds)} | {result.median_ms:.2f} "
                     f"| {result.min_ms:.2f} | {result.max_ms:.2f} "
                     f"| {result.windows_per_frame:.0f} | {_ratio(speedup(reference, result))} "
                     f"| {_ratio(speedup(opencv, result))} |")
    return "\n".join(lines)


def stage_split(result):
    """fastdet's mean milliseconds per stage, with the unaccounted rest as Python overhead."""
    named = {label: result.stages.get(stage, 0.0) for stage, label in STAGE_LABELS.items()}
    total = result.stages.get("total", 0.0)
    named["python overhead"] = max(total - sum(named.values()), 0.0)
    named["total"] = total
    return named


def format_stages(results):
    """Markdown table of fastdet's stage split (ms per frame, mean over timed calls)."""
    rows = [r for r in results if r.stages]
    if not rows:
        return ""
    columns = list(stage_split(rows[0]))
    lines = ["| stage (ms/frame) | " + " | ".join(columns) + " |",
             "|---|" + "---:|" * len(columns)]
    for result in rows:
        split = stage_split(result)
        lines.append(f"| {result.name} | " + " | ".join(f"{split[c]:.2f}" for c in columns)
                     + " |")
    return "\n".join(lines)
