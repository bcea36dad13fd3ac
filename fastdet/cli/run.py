"""``fastdet run VIDEO``: detect and track vehicles in a video, a thin layer over VideoPipeline.

Frames are streamed from the decoder through :class:`~fastdet.video.pipeline.VideoPipeline`
to the annotated video and/or the detections file, one at a time.  A
progress bar with the frame rate goes to stderr when it is a terminal; the
run ends with a one-line summary on stdout.  Ctrl-C stops the run and still
completes both outputs with every frame processed so far.
"""

from __future__ import annotations

import contextlib
import sys
import time
from pathlib import Path

from ..errors import InputError
from ..video.detection_files import FORMATS
from .common import compile_notice, make_pipeline


def add_run_parser(subparsers):
    """Add the ``run`` command to an ``argparse`` subparsers object.

    Returns
    -------
    argparse.ArgumentParser
        The ``run`` parser; its ``handler`` default is :func:`cmd_run`.
    """
    run = subparsers.add_parser(
        "run", help="detect and track vehicles in a video",
        description="Detect and track vehicles in a video; write the annotated video and/or "
                    "a detections file.  With neither --out nor --detections, writes "
                    "<VIDEO>_fastdet.mp4 beside the input.")
    run.add_argument("video", metavar="VIDEO")
    run.add_argument("--out", metavar="OUT.mp4",
                     help="annotated video (same size and frame rate as the input)")
    run.add_argument("--detections", metavar="FILE", help="detections file")
    run.add_argument("--format", choices=FORMATS,
                     help="detections format (default: from FILE's suffix, else jsonl)")
    run.add_argument("--model", metavar="M", help="model file (.npz); default: bundled model")
    run.add_argument("--config", metavar="C",
                     help="TOML config overriding built-in defaults ([track] for video settings)")
    run.add_argument("--threads", type=int, metavar="T",
                     help="threads per frame: scales are scored concurrently (default: "
                          "NUMBA_NUM_THREADS, all cores)")
    run.add_argument("--start", type=int, default=0, metavar="F",
                     help="first frame to process (frames count from 0)")
    run.add_argument("--end", type=int, metavar="F", help="stop before frame F")
    run.add_argument("--every", type=int, metavar="N",
                     help="full detection every N-th frame; frames between reuse the last boxes "
                          "(overrides track.every)")
    run.add_argument("--track", action="store_true",
                     help="patch tracking between full detections (sets track.tracking)")
    run.add_argument("--quiet", "-q", action="store_true", help="no progress bar or notices")
    run.add_argument("--debug-view", action="store_true",
                     help="draw the live heat map and per-frame timings into the output video")
    run.set_defaults(handler=cmd_run)
    return run


class Progress:
    """A one-line progress bar with the frame rate, redrawn at most 10 times a second.

    Parameters
    ----------
    total : int or None
        Frames expected (``None``: only the count is shown).
    enabled : bool
        Draw anything at all.
    stream : file, optional
        Default ``sys.stderr``.
    """

    WIDTH = 30

    def __init__(self, total, enabled, stream=None):
        self.total = total
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self._last_draw = 0.0
        self._drawn = False

    def update(self, done, fps, force=False):
        """Show ``done`` frames processed at ``fps`` frames per second."""
        if not self.enabled:
            return
        now = time.monotonic()
        if not force and now - self._last_draw < 0.1:
            return
        self._last_draw = now
        if self.total:
            filled = min(self.WIDTH, int(self.WIDTH * done / self.total))
            bar = "#" * filled + "." * (self.WIDTH - filled)
            text = f"frame {done}/{self.total} [{bar}] {fps:5.1f} fps"
        else:
            text = f"frame {done} {fps:5.1f} fps"
        self.stream.write("\r" + text)
        self.stream.flush()
        self._drawn = True

    def clear(self):
        """Erase the bar so the next line starts clean."""
        if self._drawn:
            self.stream.write("\r\x1b[K")
            self.stream.flush()
            self._drawn = False


def default_output(video):
    """``<video>_fastdet.mp4`` beside the input video."""
    video = Path(video)
    return video.with_name(f"{video.stem}_fastdet.mp4")


def _same_file(a, b):
    return Path(a).resolve() == Path(b).resolve()


def cmd_run(args):
    """Run detection and tracking over a video (the ``run`` command).

    Returns
    -------
    int
        0 on success.

    Raises
    ------
    InputError, ModelError, ConfigError
        With a one-line message, before any output is created.
    KeyboardInterrupt
        After completing both outputs with every frame processed so far.
    """
    from ..video.detection_files import DetectionWriter
    from ..video.reader import VideoReader
    from ..video.run import stream
    from ..video.writer import VideoWriter

    out, detections_path = args.out, args.detections
    announce = out is None and detections_path is None
    if announce:
        out = default_output(args.video)
    for output in (out, detections_path):
        if output is not None and Path(args.video).exists() and _same_file(output, args.video):
            raise InputError(f"output {output} would overwrite the input video")
    if out is not None and detections_path is not None and _same_file(out, detections_path):
        raise InputError("--out and --detections name the same file")
    with contextlib.ExitStack() as stack:
        # Problems with the input, then with the model or config, then with
        # the outputs: each is reported before any output file exists.
        reader = stack.enter_context(VideoReader(args.video, args.start, args.end))
        pipeline = make_pipeline(args)
        video_out = det_out = None
        if out is not None:
            video_out = stack.enter_context(VideoWriter(out, reader.fps, reader.size,
                                                          background=True))
        if detections_path is not None:
            det_out = stack.enter_context(DetectionWriter(detections_path, args.format))
        if announce and not args.quiet:
            print(f"fastdet: no --out or --detections given; writing {out}", file=sys.stderr)
        warmup = 0.0
        warm_up = getattr(pipeline.detector, "warm_up", None)
        if warm_up is not None:
            with compile_notice(enabled=not args.quiet):
                warmup = warm_up(reader.first_frame)
        progress = Progress(reader.expected_frames,
                            enabled=not args.quiet and sys.stderr.isatty())
        # An interrupt comes back as stats.interrupted, so leaving this block
        # normally completes both outputs with every frame done so far.
        stats = stream(reader, pipeline, args.start, video_out, det_out, progress,
                       debug_view=args.debug_view, warmup=warmup)
        progress.clear()
    print(stats.summary([p for p in (out, detections_path) if p is not None]), flush=True)
    if stats.interrupted:
        raise KeyboardInterrupt
    return 0
