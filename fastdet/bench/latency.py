"""The latency comparison of ``fastdet bench``: fastdet per thread count against its peers.

The slow reference is timed on a subsample of the frames and compared with
fastdet's times on exactly those frames; OpenCV is timed on every frame, in
turn with fastdet's thread counts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from ..detector.detector import Detector
from ..errors import InputError
from .peers import OpenCVPeer, load_reference_module
from .timing import (STAGE_LABELS, TURN_FRAMES, fastdet_name, speedup, spread_indices,
                     time_callable, time_fastdet_in_turn)


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
                  model=None, config=None, log=print, turn_frames=TURN_FRAMES):
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
        As for :class:`~fastdet.detector.detector.Detector` (``None``: bundled model,
        built-in config).
    log : callable
        Receives progress and skip notes.
    turn_frames : int
        Consecutive frames each pipeline is timed on per turn (see
        :func:`~fastdet.bench.timing.time_fastdet_in_turn`).

    Returns
    -------
    BenchmarkRun
    """
    size = (frames[0].shape[1], frames[0].shape[0])
    notes = []
    threads = sorted(set(threads))

    # fastdet's thread counts and OpenCV in turns of a few frames (a slow spell
    # of the machine hits them alike), then the slow reference.
    detectors = [Detector(model=model, config=config, threads=count) for count in threads]
    names = [fastdet_name(detector.threads) for detector in detectors]
    plans = detectors[0].plans(size)
    model_obj, config_obj = detectors[0].model, detectors[0].config
    opencv_peer = (_OpenCVInTurn(frames, plans, threads, repeat, model_obj, notes, log)
                   if opencv else None)
    timed = names + (["OpenCV's HOGDescriptor"] if opencv_peer and opencv_peer.peer else [])
    log(f"timing {', '.join(timed)} on {len(frames)} frames, in turns of {turn_frames} frames ...")
    try:
        fastdet_results = time_fastdet_in_turn(list(zip(names, detectors)), frames, repeat,
                                               also=opencv_peer, turn_frames=turn_frames)
    finally:
        opencv_results, opencv_report = (opencv_peer.finish() if opencv_peer is not None
                                          else ([], None))
    first, peer_results = fastdet_results[0], []
    Detector(model=model_obj, config=config_obj, threads=1)  # the reference gets one thread too

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
    results = fastdet_results + peer_results + opencv_results
    for note in notes:
        log(note)
    return BenchmarkRun(results, len(frames), size, plans, notes, opencv_report)


class _OpenCVInTurn:
    """The OpenCV peer's part of each turn; a peer that fails leaves a note, not a failure."""

    def __init__(self, frames, plans, threads, repeat, model, notes, log):
        self.notes, self.peer = notes, None
        if model.options.pixels_per_cell != 8:
            notes.append("OpenCV peer skipped: it needs 8-pixel cells")
            return
        log("starting the OpenCV HOGDescriptor peer (its own environment) ...")
        self._guarded(self._start, frames, plans, threads, repeat)

    def __call__(self, indices):
        if self.peer is not None:
            self._guarded(self.peer.time_turn, indices)

    def finish(self):
        """The peer's results and report (none after a failure); ends the peer."""
        if self.peer is None:
            return [], None
        self.peer.close()
        return self.peer.results(), self.peer.report

    def _start(self, frames, plans, threads, repeat):
        # Made here, not before the guard: the job names the training data,
        # which a bench of the user's own video may not have.
        self.peer = OpenCVPeer(frames, plans, threads, repeat)
        self.peer.start()

    def _guarded(self, step, *args):
        try:
            step(*args)
        except (InputError, OSError) as exc:
            self.notes.append(f"OpenCV peer skipped: {exc}")
            if self.peer is not None:
                self.peer.close()
            self.peer = None


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


def format_threads(results):
    """Markdown table: how each fastdet thread spent the frame, and the speed-up over 1 thread.

    A thread's busy time is its colour conversion and scoring; the rest of
    the frame it waited for the others or (the calling thread) found the
    boxes.  Idle share: ``1 - sum(busy) / (threads * total)``.  CPU time is
    the busy time less what other processes took from the thread.
    """
    rows = [r for r in results if r.thread_busy and r.stages]
    if not rows:
        return ""
    single = next((r for r in rows if len(r.thread_busy) == 1), None)
    lines = ["| pipeline | total ms/frame | busy ms per thread | CPU ms per thread | idle share "
             "| x faster than 1 thread (median) | idle-core estimate ms (from CPU time) "
             "| x faster than 1 thread (estimate) |", "|---|---:|---|---|---:|---:|---:|---:|"]
    for result in rows:
        total = result.stages.get("total", 0.0)
        busy = " / ".join(f"{ms:.2f}" for ms in result.thread_busy)
        cpu = " / ".join(f"{ms:.2f}" for ms in result.thread_cpu)
        idle = 1 - sum(result.thread_busy) / (len(result.thread_busy) * total) if total else 0.0
        ratio = single.median_ms / result.median_ms if single else math.nan
        estimate = (single.idle_estimate_ms / result.idle_estimate_ms if single
                    else math.nan)
        lines.append(f"| {result.name} | {total:.2f} | {busy} | {cpu} | {idle:.0%} "
                     f"| {_ratio(ratio)} | {result.idle_estimate_ms:.2f} | {_ratio(estimate)} |")
    return "\n".join(lines)
