"""The video pipeline's throughput: threads sharing each frame, or scoring frames at once.

``fastdet bench`` times :class:`~fastdet.video.pipeline.VideoPipeline` (the
default ``[track]`` settings: every frame searched, heat smoothed, ids) over
the benchmark's frames in two ways per thread count: a detector whose
threads share each frame, and as many single-thread detectors scoring that
many frames at once (:mod:`fastdet.video.ahead`).  Passes of all settings
alternate (round-robin) and the median pass is kept, so a slow spell of a
shared machine hits every setting alike.

Each row also counts how often the process's threads went to sleep per
frame (voluntary context switches): with two threads, the GIL taken back
after each kernel call is what they mostly wait for.

With ``processes`` (:class:`~fastdet.bench.pipeline_processes.PipelineProcesses`)
each round also times the 1-thread pass in separate processes, one alone and
all at once: what the machine gives that many copies of the pass with no GIL
shared, against which frames at once in one process are judged (their
*share*: per round, their speed-up over one thread divided by the processes'
speed-up over one process alone).

A pass is the frames played forward and back to at least
:data:`MIN_PASS_FRAMES` frames: a steady-state rate.  Passes of the test
clip's 38 frames alone last about 0.1 s, and on the 2-core machines here
their ratios of two threads to one swung between 1.15x and 1.66x from run to
run (1.70-1.82x over 380 frames).
"""

from __future__ import annotations

import statistics
from dataclasses import dataclass

try:
    import resource
except ImportError:  # Windows has no resource module: no context-switch counts
    resource = None

from ..detector.detector import Detector
from ..video.config import TrackConfig
from ..video.memory import reuse_freed_frames
from ..video.pipeline import VideoPipeline
from .pipeline_processes import WorkerError, copies_ratio, timed_pass


#: Frames a timed pass holds at least (see :func:`looped`).
MIN_PASS_FRAMES = 300


def looped(frames, count=MIN_PASS_FRAMES):
    """``frames`` played forward, back, forward, ... to at least ``count`` frames
    (no copies; a video with no cut, for the tracker)."""
    sequence, forward = [], True
    while frames and len(sequence) < count:
        sequence += frames if forward else frames[::-1]
        forward = not forward
    return sequence or list(frames)


@dataclass
class PipelinePoint:
    """Milliseconds per frame of one way of running the pipeline, median over passes."""

    threads: int
    frames_at_once: int
    ms_per_frame: float
    cpu_ms_per_frame: float
    #: Median over rounds of one thread's time over this one's in the same round.
    paired_speedup: float | None = None
    #: Median over passes of the process's voluntary context switches per frame
    #: (a thread going to sleep: waiting for the GIL, a lock or work); ``None``
    #: where the OS does not count them.
    switches_per_frame: float | None = None
    #: Separate processes running the 1-thread pass at once (0: threads of this
    #: process); their ``paired_speedup`` is over one of them alone.
    processes: int = 0
    #: Frames at once: median over rounds of their speed-up over one thread
    #: divided by the processes' speed-up in the same round (``None``: no
    #: processes timed).
    share_of_processes: float | None = None


def frame_level_study(frames, threads=(1, 2), rounds=3, model=None, config=None, log=print,
                      min_frames=MIN_PASS_FRAMES, processes=None):
    """Time the pipeline per thread count, threads per frame against frames at once.

    Parameters
    ----------
    frames : list of ndarray
        BGR frames of one size, processed in order as a video (see
        :func:`looped`: each pass plays them forward and back to at least
        ``min_frames``).
    threads : sequence of int
        Thread counts; 1 is always timed (the baseline).
    rounds : int
        Round-robin passes over all settings.
    model, config
        As for :class:`~fastdet.detector.detector.Detector`.
    min_frames : int
        Frames a pass holds at least.
    processes : callable, optional
        ``processes(looped_frames, count)``: a context manager for ``count``
        worker processes timing the 1-thread pass on those frames (such as
        :class:`~fastdet.bench.pipeline_processes.PipelineProcesses`); count is
        the largest thread count.

    Returns
    -------
    list of PipelinePoint
        One thread first, then per count above 1: threads sharing each
        frame, then frames at once; last, with ``processes``, the processes
        at once.
    """
    # Threads allocate frame-sized arrays in arenas of their own, which glibc
    # trims and refaults every frame unless told otherwise (see
    # fastdet.video.memory): frames at once cost 5-35 % more CPU without it.
    reuse_freed_frames()
    frames = looped(list(frames), min_frames)
    settings = [(1, 1)]
    for count in sorted(set(threads) - {1}):
        settings += [(count, 1), (count, count)]
    pipelines = {}
    for count, at_once in settings:
        detector = Detector(model=model, config=config, threads=1 if at_once > 1 else count)
        pipelines[count, at_once] = VideoPipeline(detector, TrackConfig())
    wall = {key: [] for key in settings}
    cpu = {key: [] for key in settings}
    switches = {key: [] for key in settings}
    copies = max(count for count, _ in settings)
    if processes is None or copies < 2:
        return _points(settings, wall, cpu, switches, _time_rounds(
            settings, pipelines, frames, rounds, log, wall, cpu, switches))
    log(f"starting {copies} pipeline processes ...")
    try:
        with processes(frames, copies) as workers:
            together = _time_rounds(settings, pipelines, frames, rounds, log, wall, cpu,
                                    switches, workers, copies)
    except WorkerError as error:
        # The processes only put the threads' figures in context: without them the
        # table is still whole (the rounds timed so far are thrown away).
        log(f"note: the pipeline processes were left out: {error}")
        for times in (*wall.values(), *cpu.values(), *switches.values()):
            times.clear()
        together = _time_rounds(settings, pipelines, frames, rounds, log, wall, cpu, switches)
    return _points(settings, wall, cpu, switches, together)


def _time_rounds(settings, pipelines, frames, rounds, log, wall, cpu, switches, workers=None,
                 copies=0):
    """Round-robin passes of every setting into ``wall``, ``cpu`` and ``switches``
    (and of the worker processes, one alone, then ``copies`` at once); returns
    the workers' rounds, each ``(alone, at_once, at_once_cpu)``: lists of ms a
    frame, one per worker timed."""
    together = []
    for round_index in range(rounds + 1):
        if round_index:
            log(f"pipeline round {round_index}/{rounds} ...")
        for key in settings:
            switches_before = _voluntary_switches()
            wall_s, cpu_s = timed_pass(pipelines[key], frames, workers=key[1])
            slept = (None if switches_before is None
                     else _voluntary_switches() - switches_before)
            # Round 0 loads every kernel and fills every buffer: not kept.
            if round_index:
                wall[key].append(wall_s / len(frames) * 1e3)
                cpu[key].append(cpu_s / len(frames) * 1e3)
                if slept is not None:
                    switches[key].append(slept / len(frames))
        # The workers ran a first pass when they started.
        if round_index and workers is not None:
            together.append((workers.passes(1), workers.passes(copies)))
    return [([wall_s * 1e3 / len(frames) for wall_s, _ in alone],
             [wall_s * 1e3 / len(frames) for wall_s, _ in at_once],
             [cpu_s * 1e3 / len(frames) for _, cpu_s in at_once])
            for alone, at_once in together]


def _points(settings, wall, cpu, switches, together):
    base = wall[settings[0]]
    points = [PipelinePoint(count, at_once, statistics.median(wall[count, at_once]),
                            statistics.median(cpu[count, at_once]),
                            paired_speedup(base, wall[count, at_once]),
                            statistics.median(switches[count, at_once])
                            if switches[count, at_once] else None)
              for count, at_once in settings]
    if not together:
        return points
    copies = len(together[0][1])
    # ms a frame of throughput: the copies' frames over the time the last one took.
    ratios = [copies_ratio(alone[0], at_once) for alone, at_once, _ in together]
    points.append(PipelinePoint(
        copies, copies, statistics.median(max(at_once) / copies for _, at_once, _ in together),
        statistics.median(sum(cpus) / copies for _, _, cpus in together),
        statistics.median(ratios), None, processes=copies))
    at_once = next(p for p in points if p.threads == copies and p.frames_at_once == copies
                   and not p.processes)
    at_once.share_of_processes = statistics.median(
        (one / this) / ratio
        for one, this, ratio in zip(base, wall[copies, copies], ratios))
    return points


def _voluntary_switches():
    """The process's voluntary context switches so far (all its threads), or ``None``.

    Each is a thread that went to sleep and is woken again: on the 2-core
    virtual machines here a wake-up takes 35-50 us and, with two frames scored
    at once, the scheduler's switching code used about 0.13 ms of CPU a
    frame (sampled with ``perf``): the table shows how often it happens.
    """
    if resource is None:
        return None
    return resource.getrusage(resource.RUSAGE_SELF).ru_nvcsw


def paired_speedup(baseline, times):
    """Median over rounds of ``baseline[k] / times[k]``.

    A slow spell of a shared machine lasts seconds: the ratio of one round's
    passes, which follow each other, is steadier than a ratio of medians taken
    from different rounds (on the 2-core machines here, per-round ratios of
    two threads to one ranged over 1.4-2.3x within one run).
    """
    return statistics.median(one / this for one, this in zip(baseline, times))


def format_frame_level(points):
    """Markdown table of :func:`frame_level_study`, each row against one thread."""
    base = next(p for p in points if p.threads == 1)
    lines = ["| pipeline | ms per frame | CPU ms per frame | x faster than 1 thread "
             "| x faster, median of per-round ratios | threads put to sleep per frame |",
             "|---|---:|---:|---:|---:|---:|"]
    for point in points:
        if point.processes:
            name = f"{point.processes} processes of 1 thread at once (no GIL shared)"
        elif point.threads == 1:
            name = "1 thread"
        elif point.frames_at_once > 1:
            name = f"{point.threads} threads, {point.frames_at_once} frames at once"
        else:
            name = f"{point.threads} threads sharing each frame"
        paired = f"{point.paired_speedup:.2f}x" if point.paired_speedup else "-"
        slept = "-" if point.switches_per_frame is None else f"{point.switches_per_frame:.1f}"
        lines.append(f"| {name} | {point.ms_per_frame:.2f} | {point.cpu_ms_per_frame:.2f} "
                     f"| {base.ms_per_frame / point.ms_per_frame:.2f}x | {paired} | {slept} |")
    processes = next((p for p in points if p.processes), None)
    shared = next((p for p in points if p.share_of_processes is not None), None)
    if processes is not None:
        lines.append(f"\nThe processes' per-round ratio is over one of them alone: what this "
                     f"machine gives {processes.processes} copies of the 1-thread pass when no "
                     "GIL is shared.")
    if shared is not None:
        lines.append(f"{shared.threads} frames at once in one process reached "
                     f"{100 * shared.share_of_processes:.0f} % of the processes' speed-up "
                     "(median over rounds of the two speed-ups' ratio in the same round).")
    return "\n".join(lines)
