"""``fastdet bench``: per-frame latency of fastdet and its peers, side by side.

Every pipeline runs on the same decoded frames in the same process, so ratios
are measured under the same machine load.  Peers that need extra packages
(the seed-faithful reference needs scikit-image) are loaded from the
checkout's ``benchmarks/`` folder when it is there.
"""

from __future__ import annotations

import importlib.util
import statistics
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from .detect import STAGES, Detector
from .errors import InputError


@dataclass
class PipelineResult:
    """Timings of one pipeline over the benchmark frames."""

    name: str
    seconds: list
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


def read_frames(video, count=None, size=None):
    """Decode up to ``count`` frames of a video, optionally resized to ``size``."""
    capture = cv2.VideoCapture(str(video))
    if not capture.isOpened():
        raise InputError(f"cannot open video {video}")
    frames = []
    try:
        while count is None or len(frames) < count:
            ok, frame = capture.read()
            if not ok:
                break
            if size is not None and (frame.shape[1], frame.shape[0]) != size:
                frame = cv2.resize(frame, size, interpolation=cv2.INTER_AREA)
            frames.append(frame)
    finally:
        capture.release()
    if not frames:
        raise InputError(f"no frames could be read from {video}")
    return frames


def time_fastdet(detector, frames, repeat=3, name="fastdet"):
    """Per-frame latency of a Detector: median over ``repeat`` passes per frame."""
    detector(frames[0])  # compile / load kernels outside the timing
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
    return PipelineResult(name, per_frame, windows / len(frames), stages)


def time_callable(name, detect, frames, windows_per_frame):
    """Per-frame latency of any callable peer (one pass; peers are slow)."""
    detect(frames[0])
    seconds = []
    for frame in frames:
        start = time.perf_counter()
        detect(frame)
        seconds.append(time.perf_counter() - start)
    return PipelineResult(name, seconds, windows_per_frame)


def load_reference_module():
    """The seed-faithful reference from the checkout's ``benchmarks/``, or None."""
    candidates = [Path.cwd() / "benchmarks" / "reference.py",
                  Path(__file__).resolve().parent.parent / "benchmarks" / "reference.py"]
    for path in candidates:
        if path.is_file():
            spec = importlib.util.spec_from_file_location("fastdet_bench_reference", path)
            module = importlib.util.module_from_spec(spec)
            sys.modules[spec.name] = module
            spec.loader.exec_module(module)
            return module
    return None


def format_table(results, reference_name="reference"):
    """Markdown table of results with ratios to the reference."""
    by_name = {result.name: result for result in results}
    reference = by_name.get(reference_name)
    lines = ["| pipeline | median ms | min ms | max ms | windows/frame | x faster than reference |",
             "|---|---:|---:|---:|---:|---:|"]
    for result in results:
        ratio = f"{reference.median_ms / result.median_ms:.0f}x" if reference else "n/a"
        lines.append(f"| {result.name} | {result.median_ms:.2f} | {result.min_ms:.2f} | "
                     f"{result.max_ms:.2f} | {result.windows_per_frame:.0f} | {ratio} |")
    return "\n".join(lines)


def format_stages(result):
    """One line: the fastdet stage split in milliseconds per frame."""
    total = result.stages.get("total", 0.0)
    named = {k: v for k, v in result.stages.items() if k != "total"}
    overhead = total - sum(named.values())
    parts = [f"{name} {ms:.2f}" for name, ms in named.items()]
    parts.append(f"python/other {overhead:.2f}")
    return f"{result.name} stages (ms/frame): " + ", ".join(parts) + f"; total {total:.2f}"


def run_benchmark(video, frames=None, threads=(1,), size=None, repeat=3, reference_frames=5,
                  model=None, config=None, log=print):
    """Time fastdet (per thread count) and the reference on the same frames."""
    decoded = read_frames(video, frames, size)
    results = []
    for count in threads:
        detector = Detector(model=model, config=config, threads=count)
        results.append(time_fastdet(detector, decoded, repeat, name=f"fastdet {count} thread"
                                    + ("s" if count > 1 else "")))
    reference = load_reference_module() if reference_frames else None
    if reference is not None:
        detector = Detector(model=model, config=config, threads=1)
        peer = reference.ReferenceDetector(detector.model, detector.config)
        step = max(1, len(decoded) // reference_frames)
        sample = decoded[::step][:reference_frames]
        results.append(time_callable("reference", peer, sample, results[0].windows_per_frame))
    elif reference_frames:
        log("reference pipeline not found (needs the checkout's benchmarks/ and scikit-image)")
    return results, len(decoded)
