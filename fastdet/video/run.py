"""One video through the detector to its outputs, pipelined: :func:`process_video`.

``fastdet run`` is a thin layer over :func:`process_video`, and so is the
batch runner (one call per video or per frame range).  The stages and their
threads are in :mod:`.stages`; this module opens the input and the outputs
in the right order (every problem with them is reported before any output
exists), wires the stages, handles Ctrl-C and SIGTERM, and reports.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import signal
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from ..detector.config import DetectorConfig, load_config
from ..detector.detector import Detector
from ..errors import InputError
from ..files.atomic import refuse_overwriting_inputs, same_file
from .ahead import can_look_ahead
from .config import TrackConfig, load_track_config
from .detection_files import DetectionWriter
from .horizon import resolve_video_horizon
from .memory import reuse_freed_frames
from .pipeline import VideoPipeline, detector_problem
from .sink import VideoSink, refuse_encoder_options_without_video
from .source import DEFAULT_TIMEOUT, VideoSource, source_file, whole_frame_number
from .standard_output import ReaderGone
from .stages import (QUEUE_FRAMES, Conveyor, StageTimes, ThreadPlan, decode, detect, encode,
                     plan_threads, report, run_cores, warm_up_queue_frames)

#: The stages of a run, in pipeline order.
RUN_STAGES = ("decode", "detect", "encode", "write")


class RunInterrupted(KeyboardInterrupt):
    """Ctrl-C or SIGTERM stopped the run; ``signum`` says which (exit status 128 + signum)."""

    def __init__(self, signum=signal.SIGINT):
        super().__init__(signal.Signals(signum).name)
        self.signum = int(signum)


@dataclass
class RunStats:
    """What a run did, for its summary line and the benchmarks."""

    frames: int = 0
    boxes: int = 0
    track_ids: set = field(default_factory=set)
    full_searches: int = 0
    wall: float = 0.0
    #: Seconds spent loading (or compiling) the kernels before the first frame; not in ``wall``.
    warmup: float = 0.0
    #: The estimate of an ``"auto"`` horizon (``None``: the configured one was searched).
    horizon: object = None
    #: The signal that stopped the run early (``None``: it ran to the end).
    interrupted: int | None = None
    #: Frames left out by ``realtime`` because processing fell behind.
    dropped: int = 0
    #: Frames nothing looked at that stayed undecoded (:mod:`fastdet.video.skipping`).
    undecoded: int = 0
    #: Why a live stream stopped (``None``: it ended normally).
    ended: str | None = None
    #: What was damaged in the input and skipped or concealed (``None``: nothing).
    damage: str | None = None
    #: Whether an output on standard output lost its reader (``| head``), which stopped the run.
    reader_gone: bool = False
    times: StageTimes = field(default_factory=StageTimes)
    plan: ThreadPlan | None = None

    @property
    def fps(self):
        return self.frames / self.wall if self.wall > 0 else 0.0

    def cpu_ms_per_frame(self):
        """CPU milliseconds per output frame of each stage's thread, and of the codec threads.

        ``codec threads`` is the CPU of the threads FFmpeg, x264 and the
        detector's scale pool run besides the stage threads.
        """
        frames = max(self.frames, 1)
        stages = self.times.stages
        result = {name: stages[name].cpu * 1e3 / frames for name in RUN_STAGES if name in stages}
        others = self.times.process_cpu - sum(clock.cpu for clock in stages.values())
        result["codec threads"] = max(others, 0.0) * 1e3 / frames
        return result

    def summary(self, outputs):
        """The one-line report printed at the end of a run."""
        per_frame = ", ".join(f"{name} {ms:.1f}" for name, ms in self.cpu_ms_per_frame().items())
        head = "interrupted after " if self.interrupted else ""
        dropped = f", {self.dropped} dropped (--realtime)" if self.dropped else ""
        if self.undecoded:
            dropped += f" ({self.undecoded} not looked at left undecoded)"
        bound = self.times.bound()
        bound = f"; bound by {bound}" if bound and self.frames else ""
        written = "; wrote " + ", ".join(str(p) for p in outputs) if outputs else ""
        ended = "".join(f"; {note}" for note in (self.ended, self.damage) if note)
        return (f"{head}{self.frames} frames{dropped}, {self.boxes} detections, "
                f"{len(self.track_ids)} tracks, {self.full_searches} full searches, "
                f"{self.fps:.1f} fps; ms/frame: {per_frame} (CPU){bound}; kernels ready in "
                f"{self.warmup:.1f} s before the first frame (not in fps){ended}{written}")


# -- signals ------------------------------------------------------------------------------
class _SignalGuard:
    """What Ctrl-C and SIGTERM do at each moment of a run.

    * While setting up (opening the input, warming up the kernels): raise
      :class:`RunInterrupted` at once; but while an output is being created
      (:meth:`deferred`), at the end of that, so no temporary file is orphaned.
    * Once the stages start (:meth:`running`): the first signal stops reading
      (the frames read still reach both outputs), a second aborts.  From then
      on a signal never raises, so completing or discarding the outputs is
      never cut short: a temporary file is always either renamed or removed.
    """

    def __init__(self, conveyor, stats):
        self.conveyor, self.stats = conveyor, stats
        self._mode = "raise"
        self._pending = None

    def handle(self, signum, _frame=None):
        self.stats.interrupted = self.stats.interrupted or signum
        if self._mode == "raise":
            raise RunInterrupted(signum)
        if self._mode == "defer":
            self._pending = self._pending or signum
        elif self.conveyor.stopping.is_set():
            self.conveyor.abort()      # a second signal: give up at once
        else:
            self.conveyor.stop()

    @contextlib.contextmanager
    def deferred(self):
        """A block a signal does not interrupt; it raises at the block's end instead."""
        self._mode = "defer"
        try:
            yield
        finally:
            self._mode = "raise"
        if self._pending:
            raise RunInterrupted(self._pending)

    def running(self):
        """From now on signals stop and abort the stages, and never raise."""
        if self._pending:
            self.conveyor.stop()
        self._mode = "run"


@contextlib.contextmanager
def _signals(conveyor, stats):
    """Install a :class:`_SignalGuard` for SIGINT and SIGTERM during the block; yield it.

    Only the main thread can handle signals; elsewhere (a worker thread of a
    batch runner) the caller's own handling stays in force.
    """
    guard = _SignalGuard(conveyor, stats)
    if threading.current_thread() is not threading.main_thread():
        yield guard
        return
    previous = {signum: signal.signal(signum, guard.handle)
                for signum in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield guard
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


# -- the run ------------------------------------------------------------------------------
def _settings(detector, config):
    """``(TrackConfig, DetectorConfig or None)`` from what :func:`process_video` was given."""
    if isinstance(detector, VideoPipeline):
        return detector.config, None
    if config is None or isinstance(config, TrackConfig):
        return config or TrackConfig(), None
    if isinstance(config, DetectorConfig):
        return TrackConfig(), config
    if isinstance(config, (str, Path)):
        return load_track_config(config), load_config(config)
    raise InputError(f"config must be a TOML path, a TrackConfig or a DetectorConfig, "
                     f"not {type(config).__name__}")


def refuse_clashing_outputs(source, target, detections, inputs=()):
    """Raise :class:`InputError` when the annotated video or the detections file
    would replace the video read, one of ``inputs`` (files such as the model and
    the config) or each other, before anything is opened.

    Parameters
    ----------
    source : str, Path, int or VideoSource
        As :func:`process_video` takes it (a camera or a URL replaces no file).
    target, detections : str or Path or None
        The outputs (``"-"`` for the detections: standard output).
    inputs : sequence of str or Path or None
        Other files the run reads.
    """
    read = [source_file(source), *inputs]
    for output in (target, detections):
        refuse_overwriting_inputs(output, read)
    if target is not None and detections is not None and (
            Path(target).resolve() == Path(detections).resolve()
            or same_file(target, [detections]) is not None):
        raise InputError(f"cannot write {target}: the video and the detections name the "
                         "same file")


def process_video(source, target=None, detector=None, config=None, callback=None, *,
                  detections=None, detections_format=None, start=0, end=None, warmup=0,
                  codec=None, crf=None, preset=None, threads=None, realtime=False,
                  debug_view=False, timeout=DEFAULT_TIMEOUT, strict=False, progress=None,
                  log=None, warm_up_notice=None):
    """Detect and track vehicles in a video, writing the annotated video and/or detections.

    Decoding, detection+tracking, drawing+encoding and the detections file run
    as pipelined stages (:mod:`fastdet.video.stages`); the detections are the
    same as those of a plain loop over :class:`VideoPipeline`.

    Parameters
    ----------
    source : str, Path, int or VideoSource
        A file, URL or camera (see :class:`VideoSource`), or an open source
        none of whose frames were read yet.
    target : str or Path, optional
        The annotated video (H.264 in MP4 by default).
    detector : Detector or VideoPipeline, optional
        Default: the bundled model with ``config``'s settings.  A
        ``VideoPipeline`` is reset first, so that each run starts as a fresh
        one would (nothing of a previous run's tracks or heat carries over).
    config : str, Path, TrackConfig or DetectorConfig, optional
        A TOML file (its detector sections and ``[track]``), or one of the
        two settings objects; a ``VideoPipeline`` brings its own.
    callback : callable, optional
        ``callback(frame_index, detections)`` for every output frame, in
        order, on the output thread.
    detections : str or Path, optional
        The detections file; ``detections_format`` is ``jsonl``, ``csv`` or
        ``mot`` (default: from the suffix).
    start, end : int
        The frames ``[start, end)`` go to the outputs (frames count from 0).
    warmup : int
        Frames before ``start`` run through the detector and tracker first,
        their outputs discarded, so a range of a long video starts with the
        temporal state a run from the beginning would have had (a batch runner
        splits a video into ranges this way).
    codec, crf, preset : str, int, str, optional
        See :class:`VideoSink` (default: the container's codec at its
        defaults, H.264 but for VP9 in a ``.webm``).  Without a
        ``target`` they would decide nothing: giving one is an
        :class:`InputError`.
    threads : int, optional
        Cores the whole run may keep busy (default and most
        ``NUMBA_NUM_THREADS``; see :func:`~fastdet.video.stages.run_cores`),
        shared between the decoder, the detector and the encoder by
        :func:`plan_threads`.  Two or more detector threads score as many
        frames at once, one each (:mod:`fastdet.video.ahead`), unless patch
        tracking, ``realtime`` or ``debug_view`` needs frames one at a time;
        the process's malloc thresholds are then set for frame-sized arrays
        (:func:`fastdet.video.memory.reuse_freed_frames`).
    realtime : bool
        Never let the input wait: when processing falls behind, only the
        newest frame is kept (``RunStats.dropped`` counts the rest); a file is
        read at its own frame rate.
    debug_view : bool
        Draw the live heat map and the detector's timings into the video.
    timeout : float
        Seconds a network source or camera may stay silent.
    strict : bool
        Damaged input (a file cut short, undecodable data, frames decoded
        with errors) is an :class:`InputError`.  By default decoding goes on
        wherever it can and ``RunStats.damage`` says what happened.
    progress : callable, optional
        ``progress(frames_done, frames_expected or None)`` about 10 times a
        second, on the calling thread.
    log : callable, optional
        Receives notes such as the thread plan (``--verbose``).
    warm_up_notice : callable, optional
        Returns a context manager wrapped around the kernels' warm-up.

    Returns
    -------
    RunStats
        With ``interrupted`` set when Ctrl-C or SIGTERM stopped the run early:
        both outputs then hold every frame completed before it.

    Raises
    ------
    InputError, ModelError, ConfigError
        One-line problems; those of the input and the outputs come before any
        output exists.  On any error the outputs are discarded: nothing is
        left under their names (a stream or FIFO keeps what it was sent).
    RunInterrupted
        A second Ctrl-C or SIGTERM (the outputs are discarded), or one before
        the first frame was done (no output is written).
    ReaderGone
        Standard output's reader closed it before the first frame; later, the
        run stops as after Ctrl-C and ``RunStats.reader_gone`` says so.
    """
    # Whole frame numbers: int() truncated start=1.5 to frame 1 before the
    # source could refuse it.
    start, warmup = whole_frame_number(start, "start"), whole_frame_number(warmup, "warmup")
    if warmup < 0:
        raise InputError(f"warmup must be >= 0, got {warmup}")
    for name, function in (("callback", callback), ("progress", progress), ("log", log),
                           ("warm_up_notice", warm_up_notice)):
        # Found here rather than as a TypeError on a stage thread mid-run.
        if function is not None and not callable(function):
            raise InputError(f"{name} must be callable, got {type(function).__name__}")
    if detector is not None and not isinstance(detector, VideoPipeline):
        # A model path given here failed with an AttributeError deep in the pipeline.
        # VideoPipeline's own rule (all three methods, an instance), so that one
        # lacking some of them is this one-line InputError too, not its TypeError.
        problem = detector_problem(detector)
        if problem is not None:
            raise InputError(f"detector must be a Detector or a VideoPipeline, not "
                             f"{type(detector).__name__} ({problem.split('; ')[-1]}; a "
                             f"model file: Detector(model=...))")
    if isinstance(source, VideoSource):
        _refuse_used_source(source)
    if target is None:
        refuse_encoder_options_without_video(codec, crf, preset)
    refuse_clashing_outputs(source, target, detections,
                            [config] if isinstance(config, (str, os.PathLike)) else [])
    cores = run_cores(threads)
    stats = RunStats()
    conveyor = Conveyor()
    outputs = []
    with _signals(conveyor, stats) as guard, contextlib.ExitStack() as stack:
        try:
            track_config, detector_config = _settings(detector, config)
            period = track_config.search_period
            plan = stats.plan = plan_threads(cores, target is not None,
                                             1.0 / period if period else 1.0)
            # Several detector threads score that many frames at once, one
            # each, where the frames to search are known ahead (no patch
            # tracking) and latency is not the point (no --realtime).
            frame_level = (plan.detector > 1 and not track_config.tracking and not realtime
                           and not debug_view)
            if isinstance(detector, VideoPipeline):
                pipeline = detector
                # A run starts at its video's beginning (or its warm-up frames),
                # not where the pipeline's last video left its tracks and heat.
                pipeline.reset()
            else:
                pipeline = VideoPipeline(detector or Detector(
                    config=detector_config, threads=1 if frame_level else plan.detector),
                    track_config)
            frame_level = frame_level and can_look_ahead(pipeline)
            if frame_level:
                plan = stats.plan = dataclasses.replace(plan, frames_at_once=plan.detector)
                # The detector threads allocate frame-sized arrays in arenas of
                # their own, which glibc would trim and refault every frame.
                reuse_freed_frames()
            if log is not None:
                log(plan.describe())
            if isinstance(source, VideoSource):
                video = source
            else:
                first = max(start - warmup, 0)
                video = stack.enter_context(VideoSource(source, first, end, timeout=timeout,
                                                        threads=plan.decoder, strict=strict))
            first_output = max(start, video.start)
            # An "auto" horizon: the camera's, from the file's first frames,
            # before anything is planned on it.
            stats.horizon = resolve_video_horizon(pipeline.detector, video, log)
            rows = pipeline.rows_read(video.size)
            sink = writer = None
            with guard.deferred():
                if target is not None:
                    sink = VideoSink(target, video.rate, video.size, codec, crf, preset,
                                     threads=plan.encoder, time_base=video.time_base,
                                     colour=None if debug_view else video.colour)
                    outputs.append(sink)
                if detections is not None:
                    writer = DetectionWriter(detections, detections_format)
                    outputs.append(writer)
            # Searching every frame, the detector's thread bounds the run: the
            # decoder's converts the searched rows instead (0.3-0.6 ms a frame).
            early_rows = (rows if rows is not None and period == 1 and not realtime
                          and not debug_view else None)
            # Searching every N-th frame with no video to write, the frames in
            # between are only counted: those the codec allows stay undecoded.
            needed = (pipeline.frames_needed(video.start)
                      if sink is None and not realtime and not debug_view else None)
            # The pipeline's kernels too (heat smoothing, tracking), not only the detector's.
            warm_up = pipeline.warm_up if hasattr(pipeline.detector, "warm_up") else None
            warm_up_frame = video.first_frame     # taken before the decoder starts
            # The decoder starts while the kernels load.  Where it bounds the
            # run (frames left out), its queue holds more frames until the
            # detector is ready; elsewhere the detector bounds it and the
            # memory would buy nothing.
            inbox = conveyor.frame_queue(warm_up_queue_frames(video.size)
                                         if needed is not None and warm_up is not None
                                         else QUEUE_FRAMES)
            conveyor.add("decode", decode, conveyor, video, inbox, realtime, stats, early_rows,
                         needed)
            conveyor.start("decode")
            try:
                if warm_up is not None:
                    with (warm_up_notice() if warm_up_notice else contextlib.nullcontext()):
                        stats.warmup = warm_up(warm_up_frame)
                inbox.frames = QUEUE_FRAMES
                outboxes = []
                if sink is not None:
                    outboxes.append(conveyor.queue())
                    # The video starts at 0, its frames' spacing kept, as FFmpeg's
                    # own output does (no -copyts): a live source's clock starts
                    # anywhere (a camera's uptime), a range anywhere in its file,
                    # and a batch joins its segments' videos end to end.
                    conveyor.add("encode", encode, conveyor, outboxes[-1], sink,
                                 False, inbox=outboxes[-1])
                outboxes.append(conveyor.queue())
                conveyor.add("write", report, conveyor, outboxes[-1], writer, callback, stats,
                             inbox=outboxes[-1])
                conveyor.add("detect", detect, conveyor, inbox, outboxes, pipeline, rows,
                             debug_view, first_output, stats, plan.frames_at_once, inbox=inbox)
                total = video.expected_frames
                total = None if total is None else max(total - (first_output - video.start), 0)
                tick = None if progress is None else (lambda: progress(stats.frames, total))
                guard.running()
                started = time.perf_counter()
                try:
                    conveyor.run(tick)
                finally:
                    stats.wall = time.perf_counter() - started
                    stats.times = conveyor.times
            except BaseException:
                # Before the run started (a failed warm-up, a signal), the
                # decoder is the one stage running: stop it before closing its source.
                conveyor.cancel()
                raise
            if conveyor.aborted or stats.frames == 0:
                _discard(outputs)
                if stats.interrupted:
                    raise RunInterrupted(stats.interrupted)
                return stats
            stats.reader_gone = any(output.reader_gone for output in outputs)
            for output in outputs:
                try:
                    output.close()
                except ReaderGone:
                    # Found only now when the last writes were buffered (a
                    # fragmented MP4 goes out a keyframe's group at a time).
                    stats.reader_gone = True
        except BaseException:
            guard.running()     # signals no longer raise: the discarding runs to its end
            _discard(outputs)
            raise
    return stats


def _refuse_used_source(source):
    """Raise :class:`InputError` for a source that cannot be read from its first frame.

    A run counts frames from the source's ``start`` and warms up on its
    first frame: a closed source, or one whose frames were read already,
    failed with "a frame must be a numpy array, got NoneType".
    """
    if source.closed:
        raise InputError(f"{source.name} is closed")
    if source.frames_read:
        raise InputError(f"{source.name}: {source.frames_read} frames were read already; "
                         "process_video reads a source from its start (open it again)")


def _discard(outputs):
    for output in outputs:
        output.discard()
