"""``fastdet run VIDEO``: detect and track vehicles in a video, a thin layer over process_video.

The input is a file, a URL (``http(s)://``, ``rtsp://``, ``udp://``,
``tcp://``) or a camera (``/dev/video0`` or ``0``).  Decoding, detection,
encoding and the detections file run pipelined
(:func:`fastdet.video.run.process_video`).  A tqdm progress bar (frames, fps
and, for inputs of known length, the time left) goes to stderr when it is a
terminal; the run ends with a one-line summary on stdout (on stderr when an
output is standard output).  Ctrl-C or SIGTERM stops the run and still
completes both outputs with every frame processed so far (exit status 130 or
143); a second one aborts at once, leaving no output.  A damaged input is
processed as far as the decoder can, with a warning (``--strict``: an
error).
"""

from __future__ import annotations

import re
import sys
from pathlib import Path
from urllib.parse import unquote, urlparse

from ..files.atomic import STDOUT, output_in_folder
from ..video.detection_files import FORMATS
from .common import (add_encoder_options, add_horizon_option, add_schedule_options,
                     compile_notice, make_pipeline, message_stream, track_config)


def add_run_parser(subparsers):
    """Add the ``run`` command to an ``argparse`` subparsers object.

    Returns
    -------
    argparse.ArgumentParser
        The ``run`` parser; its ``handler`` default is :func:`cmd_run`.
    """
    run = subparsers.add_parser(
        "run", help="detect and track vehicles in a video, stream or camera",
        description="Detect and track vehicles in a video file, a stream (http(s)://, rtsp://, "
                    "udp://, tcp://) or a camera (/dev/video0 or 0); write the annotated video "
                    "(H.264 MP4 that plays in a browser) and/or a detections file.  With neither "
                    "--out nor --detections, writes <VIDEO>_fastdet.mp4 beside the input.")
    run.add_argument("video", metavar="VIDEO")
    run.add_argument("--out", metavar="OUT.mp4",
                     help="annotated video (same size, frame rate and timestamps as the input); "
                          "'-', a FIFO or a device get fragmented MP4 (or the suffix's "
                          "container), written as it goes")
    run.add_argument("--detections", metavar="FILE", help="detections file ('-': stdout)")
    run.add_argument("--format", choices=FORMATS,
                     help="detections format (default: from FILE's suffix, else jsonl)")
    add_encoder_options(run)
    # Not given (rather than h264) so that --codec without a video output is refused.
    run.set_defaults(codec=None)
    run.add_argument("--model", metavar="M", help="model file (.npz); default: bundled model")
    run.add_argument("--config", metavar="C",
                     help="TOML config overriding built-in defaults ([track] for video settings)")
    add_horizon_option(run)
    run.add_argument("--threads", type=int, metavar="T",
                     help="cores the run may keep busy, shared by the decoder, the detector and "
                          "the encoder (default: NUMBA_NUM_THREADS, all cores; --verbose "
                          "prints the plan)")
    run.add_argument("--start", type=int, default=0, metavar="F",
                     help="first frame to process (frames count from 0)")
    run.add_argument("--end", type=int, metavar="F", help="stop before frame F")
    add_schedule_options(run)
    run.add_argument("--realtime", action="store_true",
                     help="keep up with a live source: when processing falls behind, keep only "
                          "the newest frame (the summary counts the dropped ones); a file is "
                          "read at its own frame rate")
    run.add_argument("--timeout", type=float, default=10.0, metavar="S",
                     help="seconds a stream or camera may stay silent (default 10)")
    run.add_argument("--strict", action="store_true",
                     help="damaged input (cut short, undecodable data, frames decoded with "
                          "errors) is an error; by default it is processed as far as the "
                          "decoder can, with a warning")
    run.add_argument("--quiet", "-q", action="store_true", help="no progress bar or notices (the summary line stays)")
    run.add_argument("--debug-view", action="store_true",
                     help="draw the live heat map and per-frame timings into the output video")
    run.set_defaults(handler=cmd_run)
    return run


class ProgressBar:
    """A tqdm bar of frames done, fps and, when the length is known, the time left.

    Created at the first update, so nothing is drawn for a run that fails
    before its first frame.
    """

    def __init__(self, enabled, stream=None):
        self.enabled = enabled
        self.stream = stream or sys.stderr
        self._bar = None

    def update(self, done, total):
        """Show ``done`` frames of ``total`` (``None``: a live source, no time left)."""
        if not self.enabled:
            return
        if self._bar is None:
            from tqdm import tqdm

            self._bar = tqdm(total=total, unit=" frames", file=self.stream, leave=False,
                             dynamic_ncols=True, mininterval=0.1, smoothing=0.1)
        self._bar.update(done - self._bar.n)

    def close(self):
        """Erase the bar so the next line starts clean."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None


def default_output(video):
    """``<video>_fastdet.mp4`` beside an input file; in the current folder for streams.

    Built from the input's name only (:func:`~fastdet.files.atomic.output_in_folder`):
    never a ``..`` or a separator from a URL, and a symbolic link already
    standing under that name is refused rather than followed.
    """
    from ..video.source import source_file

    path = source_file(video)
    if path is not None:
        return output_in_folder(path.parent, f"{path.stem}_fastdet.mp4")
    # The last part of the URL's path, decoded, in plain characters, never hidden.
    stem = re.sub(r"[^\w.-]", "_", Path(unquote(urlparse(str(video)).path)).stem).lstrip(".")
    stem = stem or "stream"
    stem = f"camera{stem}" if stem.isdigit() else stem
    return output_in_folder(Path("."), f"{stem}_fastdet.mp4")


def _plan(args, track):
    """How the run's threads are shared (the same plan process_video makes)."""
    from ..video.stages import plan_threads, run_cores

    period = track.search_period
    return plan_threads(run_cores(args.threads), args.out is not None,
                        1.0 / period if period else 1.0)


def _pipeline(args):
    return make_pipeline(args, threads=_plan(args, track_config(args)).detector)


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
    RunInterrupted
        After Ctrl-C or SIGTERM, once both outputs hold every frame processed so far.
    ReaderGone
        When an output on standard output lost its reader (``| head``), once
        the other output holds every frame processed so far.
    """
    from ..video.run import RunInterrupted, process_video, refuse_clashing_outputs
    from ..video.sink import refuse_encoder_options_without_video
    from ..video.source import VideoSource
    from ..video.standard_output import ReaderGone, writes_standard_output

    verbose = getattr(args, "verbose", False)
    out, detections_path = args.out, args.detections
    announce = out is None and detections_path is None
    if announce:
        out = args.out = default_output(args.video)
    if out is None:
        refuse_encoder_options_without_video(args.codec, args.crf, args.preset)
    # Before any work: no output may replace an input or the other output.
    refuse_clashing_outputs(args.video, out, detections_path, [args.model, args.config])
    # Problems with the input, then with the model or config, then with the
    # outputs: each is reported before any output file exists.
    plan = _plan(args, track_config(args))
    with VideoSource(args.video, args.start, args.end, threads=plan.decoder,
                     timeout=args.timeout, strict=args.strict) as source:
        pipeline = _pipeline(args)
        if announce and not args.quiet:
            print(f"fastdet: no --out or --detections given; writing {out}", file=sys.stderr)
        bar = ProgressBar(enabled=not args.quiet and sys.stderr.isatty())
        try:
            stats = process_video(
                source, out, pipeline, detections=detections_path,
                detections_format=args.format, codec=args.codec, crf=args.crf,
                preset=args.preset, threads=args.threads, realtime=args.realtime,
                debug_view=args.debug_view, strict=args.strict, progress=bar.update,
                log=(lambda line: print(f"fastdet: {line}", file=sys.stderr)) if verbose else None,
                warm_up_notice=lambda: compile_notice(enabled=not args.quiet))
        finally:
            bar.close()
    if stats.reader_gone:
        # The other output is complete; the command line ends quietly (exit 141).
        raise ReaderGone(next(p for p in (out, detections_path)
                              if p is not None and writes_standard_output(p)))
    written = [p for p in (out, detections_path)
               if p is not None and (str(p) == STDOUT or Path(p).exists())]
    if stats.horizon is not None and not args.quiet and not verbose:   # verbose: logged
        print(f"fastdet: {args.video}: {stats.horizon.describe()}; searching at "
              f"{pipeline.detector.config.search.horizon:.3f}", file=sys.stderr)
    if stats.damage:
        print(f"fastdet: warning: {args.video}: {stats.damage}", file=sys.stderr)
    print(stats.summary(written), file=message_stream(out, detections_path), flush=True)
    if stats.interrupted:
        raise RunInterrupted(stats.interrupted)
    return 0
