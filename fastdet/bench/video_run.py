"""The main job's throughput: whole ``fastdet run`` processes against OpenCV's decoding rate.

:func:`video_benchmark` makes its own input, the shared 38-frame test clip
looped forward and back to 1000 frames and encoded as H.264 (libx264,
preset medium, crf 23: about the clip's own bitrate), cached beside the
compiled kernels.  Each round measures, one after the other:

* ``R``, OpenCV's single-thread decode-only rate of that file
  (``cv2.VideoCapture`` with one FFmpeg thread, frames read and converted
  to BGR, file opening excluded), in a fresh process;
* each mode of :data:`MODES` as a fresh ``fastdet run`` process, timed from
  its start to its exit (interpreter, imports, model, kernels from the
  cache, everything): ``fps = frames / wall``.

Measured in rounds, paired: the ratio ``fps / R`` is taken within each round
and its median reported, so a busy machine slows both sides of a ratio.
Each run's summary line gives the CPU time per stage and which stage bound
it; ``os.wait4`` gives the process's CPU time and peak RSS.
"""

from __future__ import annotations

import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path

#: ``(label, fastdet run options, target as a multiple of R)``.
MODES = (
    ("every frame, annotated H.264 + detections", ("--out", "{out}", "--detections", "{dets}"),
     0.45),
    ("every frame, detections only", ("--detections", "{dets}"), 0.70),
    ("--every 5, detections only", ("--detections", "{dets}", "--every", "5"), 1.20),
    ("--every 5, annotated H.264 + detections",
     ("--out", "{out}", "--detections", "{dets}", "--every", "5"), 0.60),
)
#: Frames of the benchmark input.
LOOPED_FRAMES = 1000

_OPENCV_DECODE = r"""
import json, sys, time
import cv2
capture = cv2.VideoCapture(sys.argv[1], cv2.CAP_FFMPEG, [cv2.CAP_PROP_N_THREADS, 1])
frames, start, cpu = 0, time.perf_counter(), time.process_time()
while capture.read()[0]:
    frames += 1
print(json.dumps({"frames": frames, "seconds": time.perf_counter() - start,
                  "cpu_seconds": time.process_time() - cpu}))
"""


def pingpong(index, count):
    """Frame of a ``count``-frame clip shown at step ``index`` when looped forward and back."""
    period = 2 * count - 2
    step = index % period
    return step if step < count else period - step


def looped_video(source, frames=LOOPED_FRAMES, folder=None, preset="medium"):
    """``source`` looped forward and back to ``frames`` frames, as H.264; made once, cached.

    Parameters
    ----------
    source : str or Path
        The clip to loop.
    frames : int
    folder : str or Path, optional
        Where to keep it (default: ``bench`` beside the kernel cache).
    preset : str
        libx264's preset: ``medium`` (the benchmark's, about the clip's own
        bitrate) or a faster one for tests.

    Returns
    -------
    Path
    """
    import av

    from ..files.atomic import atomic_path
    from ..kernels.cache import kernel_cache_dir
    from ..video.source import VideoSource

    folder = Path(folder) if folder else kernel_cache_dir().parent.parent / "bench"
    speed = "" if preset == "medium" else f"_{preset}"
    path = folder / f"{Path(source).stem}_looped{frames}{speed}.mp4"
    if path.exists():
        return path
    folder.mkdir(parents=True, exist_ok=True)
    with VideoSource(source) as video:
        (matrix, colour_range), rate, (width, height) = video.colour, video.rate, video.size
        clip = [frame.to_ndarray() for frame in video.decoded_frames()]   # I420 planes
    with atomic_path(path) as partial, av.open(str(partial), "w") as container:
        stream = container.add_stream("libx264", rate=rate,
                                      options={"preset": preset, "crf": "23"})
        stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
        # Frame threads keep one slice per picture, like camera files.
        stream.codec_context.thread_type = "FRAME"
        stream.codec_context.colorspace = matrix
        stream.codec_context.color_range = colour_range
        for index in range(frames):
            frame = av.VideoFrame.from_ndarray(clip[pingpong(index, len(clip))],
                                               format="yuv420p")
            frame.pts, frame.time_base = index, Fraction(1) / rate
            container.mux(stream.encode(frame))
        container.mux(stream.encode(None))
    return path


@dataclass
class ProcessRun:
    """One child process: its wall time, CPU time, peak RSS and output."""

    wall: float
    cpu: float
    peak_rss_mib: float
    stdout: str
    returncode: int


def run_process(command, env=None):
    """Run ``command`` to its end; wall time, CPU and peak RSS from ``os.wait4``."""
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        start = time.perf_counter()
        process = subprocess.Popen(command, stdout=out, stderr=err, env=env)
        _, status, usage = os.wait4(process.pid, 0)
        wall = time.perf_counter() - start
        process.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        err.seek(0)
        text = out.read()
        if process.returncode != 0:
            raise RuntimeError(f"{' '.join(map(str, command))} failed: {err.read()[-500:]}")
    return ProcessRun(wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024, text,
                      process.returncode)


def opencv_decode_rate(path):
    """OpenCV's single-thread decoding of ``path`` in a fresh process.

    Returns
    -------
    fps : float
        Frames per second of the decoding loop (file opening excluded).
    cpu_ms : float
        CPU milliseconds per frame of that loop.
    frames : int
    """
    import json

    run = run_process([sys.executable, "-c", _OPENCV_DECODE, str(path)])
    result = json.loads(run.stdout.strip().splitlines()[-1])
    frames = result["frames"]
    return frames / result["seconds"], result["cpu_seconds"] * 1e3 / frames, frames


_SUMMARY = re.compile(r"^(?:interrupted after )?(?P<frames>\d+) frames.*ms/frame: "
                      r"(?P<stages>[^(]*) \(CPU\)(?:; bound by (?P<bound>[\w ]+))?")


def fastdet_run(path, options, threads=None, folder=None):
    """One ``fastdet run`` process over ``path``; its :class:`ProcessRun` and parsed summary."""
    folder = Path(folder or tempfile.mkdtemp(prefix="fastdet-bench-"))
    arguments = [a.format(out=folder / "out.mp4", dets=folder / "dets.jsonl") for a in options]
    command = [sys.executable, "-m", "fastdet.cli", "run", str(path), *arguments, "--quiet"]
    if threads:
        command += ["--threads", str(threads)]
    run = run_process(command)
    match = _SUMMARY.match(run.stdout.strip().splitlines()[-1])
    stages = {name.strip(): float(ms) for name, ms in
              (part.rsplit(" ", 1) for part in match["stages"].split(", "))}
    return run, int(match["frames"]), stages, match["bound"]


@dataclass
class ModeResult:
    """A mode's runs over the rounds."""

    label: str
    target: float
    fps: list = field(default_factory=list)
    ratios: list = field(default_factory=list)
    stages: list = field(default_factory=list)
    bounds: list = field(default_factory=list)
    cpu_per_frame_ms: list = field(default_factory=list)
    peak_rss_mib: list = field(default_factory=list)

    @property
    def ratio(self):
        return statistics.median(self.ratios)


@dataclass
class VideoBenchmark:
    """Everything :func:`video_benchmark` measured."""

    video: Path
    frames: int
    opencv_fps: list
    opencv_cpu_ms: list
    modes: list
    load_before: tuple
    load_after: tuple
    rss_short_mib: float | None = None
    rss_long_mib: float | None = None


def video_benchmark(source, rounds=3, threads=None, modes=MODES, rss=True, log=None):
    """Time every mode against R in ``rounds`` paired rounds (see the module's docstring).

    Parameters
    ----------
    source : str or Path
        The short clip to loop (the shared test video).
    rounds : int
    threads : int, optional
        ``--threads`` of the runs (default: the runs' own default).
    modes : sequence of (label, options, target)
    rss : bool
        Also compare the peak RSS of the annotated run on ``source`` and on
        the 1000-frame input.
    log : callable, optional
        Progress lines.

    Returns
    -------
    VideoBenchmark
    """
    log = log or (lambda line: None)
    video = looped_video(source)
    results = [ModeResult(label, target) for label, _, target in modes]
    opencv, opencv_cpu, frames = [], [], LOOPED_FRAMES
    load_before = os.getloadavg()
    for round_number in range(1, rounds + 1):
        rate, cpu_ms, frames = opencv_decode_rate(video)
        opencv.append(rate)
        opencv_cpu.append(cpu_ms)
        log(f"round {round_number}/{rounds}: OpenCV decodes at {rate:.1f} fps")
        for result, (_, options, _) in zip(results, modes):
            run, done, stages, bound = fastdet_run(video, options, threads)
            fps = done / run.wall
            result.fps.append(fps)
            result.ratios.append(fps / rate)
            result.stages.append(stages)
            result.bounds.append(bound)
            result.cpu_per_frame_ms.append(run.cpu * 1e3 / done)
            result.peak_rss_mib.append(run.peak_rss_mib)
            log(f"  {result.label}: {fps:.1f} fps = {fps / rate:.2f} R")
    benchmark = VideoBenchmark(video, frames, opencv, opencv_cpu, results, load_before,
                               os.getloadavg())
    if rss:
        annotated = modes[0][1]
        benchmark.rss_short_mib = fastdet_run(source, annotated, threads)[0].peak_rss_mib
        benchmark.rss_long_mib = fastdet_run(video, annotated, threads)[0].peak_rss_mib
    return benchmark


def format_video_benchmark(benchmark, cores=None):
    """Markdown: the modes against R and their targets, the stages, the peak RSS.

    Besides the measured ratio, each mode's *CPU ceiling* is the ratio it would
    reach if the run's CPU time per frame were spread perfectly over ``cores``
    idle cores, against OpenCV's CPU time per frame: ``cores * OpenCV CPU ms /
    fastdet CPU ms``.  CPU time hardly changes with the machine's load, so on a
    shared machine it tells what a quiet one would show (start-up included).
    """
    cores = cores or os.cpu_count() or 1
    rate = statistics.median(benchmark.opencv_fps)
    opencv_ms = statistics.median(benchmark.opencv_cpu_ms)
    lines = [f"Input: {benchmark.video} ({benchmark.frames} frames). R = OpenCV single-thread "
             f"decode-only rate, median {rate:.1f} fps over {len(benchmark.opencv_fps)} rounds "
             f"({', '.join(f'{r:.0f}' for r in benchmark.opencv_fps)}), "
             f"{opencv_ms:.2f} CPU ms per frame. Load average "
             f"{benchmark.load_before[0]:.2f} before, {benchmark.load_after[0]:.2f} after.", "",
             "| mode | fps (whole process, median) | x R (median of paired rounds) | target | "
             f"met | CPU ms/frame (process) | CPU ceiling on {cores} cores, x R | bound by |",
             "|---|---:|---:|---:|:---:|---:|---:|---|"]
    for mode in benchmark.modes:
        bound = statistics.mode(b for b in mode.bounds if b) if any(mode.bounds) else "-"
        cpu_ms = statistics.median(mode.cpu_per_frame_ms)
        lines.append(f"| {mode.label} | {statistics.median(mode.fps):.1f} | {mode.ratio:.2f} | "
                     f"{mode.target:.2f} | {'yes' if mode.ratio >= mode.target else 'no'} | "
                     f"{cpu_ms:.1f} | {cores * opencv_ms / cpu_ms:.2f} | {bound} |")
    lines += ["", "CPU ms per frame of each stage's thread (median over rounds; 'codec "
              "threads' are FFmpeg's, x264's and the detector pool's own threads):", "",
              "| mode | " + " | ".join(_stage_names(benchmark)) + " |",
              "|---|" + "---:|" * len(_stage_names(benchmark))]
    for mode in benchmark.modes:
        cells = [statistics.median(s.get(name, 0.0) for s in mode.stages)
                 for name in _stage_names(benchmark)]
        lines.append(f"| {mode.label} | " + " | ".join(f"{c:.2f}" for c in cells) + " |")
    if benchmark.rss_short_mib:
        growth = benchmark.rss_long_mib / benchmark.rss_short_mib - 1
        lines += ["", f"Peak RSS of the annotated run: {benchmark.rss_short_mib:.0f} MiB on the "
                      f"38-frame clip, {benchmark.rss_long_mib:.0f} MiB on the 1000-frame input "
                      f"({growth:+.1%})."]
    return "\n".join(lines)


def _stage_names(benchmark):
    names = []
    for mode in benchmark.modes:
        for stages in mode.stages:
            names += [name for name in stages if name not in names]
    return names
