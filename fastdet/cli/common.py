"""Options and helpers that several verbs share."""

from __future__ import annotations

import contextlib
import os
import sys
import threading


def add_model_options(parser):
    """``--model``, ``--config`` and ``--threads``: what building a detector needs."""
    parser.add_argument("--model", metavar="M", help="model file (.npz); default: bundled model")
    parser.add_argument("--config", metavar="C", help="TOML config overriding built-in defaults")
    parser.add_argument("--threads", type=int, metavar="T",
                        help="threads per frame: scales are scored concurrently (default: "
                             "NUMBA_NUM_THREADS, all cores)")


def add_horizon_option(parser):
    """``--horizon``: the ``[search] horizon`` of the command, a number or ``auto``."""
    parser.add_argument("--horizon", type=horizon_argument, metavar="H|auto",
                        help="the horizon row as a fraction of the frame height, or auto: "
                             "estimated from where the lane lines meet (overrides [search] "
                             "horizon; default 0.58)")


def horizon_argument(text):
    """``--horizon``'s value: ``"auto"`` or a float (its range is checked with the config)."""
    import argparse

    if text == "auto":
        return text
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a fraction of the frame height or auto, "
                                         f"got {text!r}") from None


def detector_config(args):
    """The :class:`DetectorConfig` of ``--config``, with ``--horizon`` applied.

    The file's ``[track]`` section is checked too, though only the video
    verbs use it: one config file serves every verb, and a mistake in it
    should not pass ``detect`` and ``eval`` only to stop a later ``run``.
    """
    from ..detector.config import load_config, with_search_horizon
    from ..video.config import load_track_config

    config = with_search_horizon(load_config(args.config), getattr(args, "horizon", None))
    load_track_config(args.config)
    return config


def make_detector(args):
    """The :class:`~fastdet.detector.detector.Detector` that ``args``' model options ask for."""
    from ..detector.detector import Detector

    return Detector(model=args.model, config=detector_config(args),
                    threads=getattr(args, "threads", None))


def resolve_images_horizon(detector, paths):
    """An ``"auto"`` horizon from images ``paths`` of one camera, reported on stderr.

    One estimate for all of them, as for a video's frames: a single frame's
    lane lines can mislead it by several times what the search tolerates (up
    to 0.13 of the frame height on the test video's frames, against a
    search that misses cars 0.03 off).
    """
    if not detector.auto_horizon:
        return None
    from ..files.images import read_image

    estimate = detector.resolve_horizon(read_image(path) for path in paths)
    print(f"fastdet: {len(paths)} image(s): {estimate.describe()}; searching at "
          f"{detector.config.search.horizon:.3f}", file=sys.stderr)
    return estimate


def message_stream(*outputs):
    """Where a command prints its messages: stderr when one of ``outputs`` is standard output.

    ``--out -`` (or ``/dev/stdout``) puts the output itself on stdout, where
    the messages would corrupt it.
    """
    for output in outputs:
        if output is None:
            continue
        if str(output) == "-":
            return sys.stderr
        with contextlib.suppress(OSError, ValueError):
            if os.path.samestat(os.stat(output), os.fstat(sys.stdout.fileno())):
                return sys.stderr
    return sys.stdout


def add_schedule_options(parser):
    """``--every`` and ``--track``: the video options :func:`track_config` applies."""
    parser.add_argument("--every", type=int, metavar="N",
                        help="full detection every N-th frame; frames between reuse the last "
                             "boxes (overrides track.every)")
    parser.add_argument("--track", action="store_true",
                        help="patch tracking between full detections (sets track.tracking)")


def add_encoder_options(parser):
    """``--codec``, ``--crf`` and ``--preset``: how the annotated video is encoded."""
    from ..video.codecs import CRF_RANGE, DEFAULT_CRF, DEFAULT_PRESET, ENCODERS

    crfs = ", ".join(f"{codec} {crf}" for codec, crf in DEFAULT_CRF.items() if codec != "mp4v")
    presets = ", ".join(f"{codec} {preset}" for codec, preset in DEFAULT_PRESET.items())
    parser.add_argument("--codec", choices=tuple(ENCODERS), default="h264",
                        help="codec of the annotated video (default h264, which plays "
                             "everywhere; vp9 in a .webm, which holds only vp9 and av1)")
    parser.add_argument("--crf", type=int, metavar="Q",
                        help=f"quality, lower is better and bigger (default: {crfs}; mp4v: "
                             f"quantiser {'-'.join(map(str, CRF_RANGE['mp4v']))}, default "
                             f"{DEFAULT_CRF['mp4v']})")
    parser.add_argument("--preset", metavar="P",
                        help=f"encoder speed preset (default: {presets})")


def track_config(args):
    """The ``[track]`` settings of ``--config``, with ``--every`` and ``--track`` applied."""
    from ..errors import InputError
    from ..video.config import load_track_config

    config = load_track_config(args.config)
    if args.every is not None:
        if args.every < 1:
            raise InputError(f"--every must be at least 1, got {args.every}")
        config = config.replace(every=args.every)
    if args.track:
        config = config.replace(tracking=True)
    return config


def make_pipeline(args, threads=None):
    """The :class:`~fastdet.video.pipeline.VideoPipeline` of ``args``' model and video options.

    ``threads``: the detector's threads (default: ``--threads``).
    """
    from ..detector.detector import Detector
    from ..video.pipeline import VideoPipeline

    detector = Detector(model=args.model, config=detector_config(args),
                        threads=threads if threads is not None else getattr(args, "threads", None))
    return VideoPipeline(detector, track_config(args))


def add_annotation_options(parser, verb):
    """``--annotations`` (one file, or one per source) and ``--split``."""
    parser.add_argument("--annotations", required=True, nargs="+", metavar="A.json",
                        help="vehicle boxes (images by file name, video frames as frame<N>): "
                             "one file for all sources or one per source, in order")
    parser.add_argument("--split", metavar="NAME",
                        help=f"{verb} only the frames each annotation file lists under NAME in "
                             f"its \"frames\" (files without splits are used whole)")


def annotated_sources(sources, annotation_paths, split=None):
    """``(source, annotations)`` pairs from the command line's sources and annotation files."""
    from ..errors import InputError
    from ..evaluation.annotations import load_annotations, load_splits, select_split

    if len(annotation_paths) not in (1, len(sources)):
        raise InputError(f"give one annotation file, or one per source ({len(sources)}), "
                         f"not {len(annotation_paths)}")
    loaded = []
    for path in annotation_paths:
        annotations, splits = load_annotations(path), load_splits(path)
        loaded.append(select_split(annotations, splits, split, path) if split and splits
                      else annotations)
    if len(loaded) == 1:
        loaded = loaded * len(sources)
    return list(zip(sources, loaded))


def log_to_stderr(line):
    """Progress lines of long commands go to stderr, flushed at once."""
    print(line, file=sys.stderr, flush=True)


#: Seconds the first detection may take before the user is told kernels are compiling;
#: loading them from the cache takes well under this.
COMPILE_NOTICE_AFTER = 1.5


@contextlib.contextmanager
def compile_notice(enabled=True, stream=None):
    """Say once, on stderr, that kernels are compiling if the block takes that long.

    Wrap the first detection of a command in it.  With a filled cache the
    block ends long before :data:`COMPILE_NOTICE_AFTER` and nothing is
    printed; with an empty one the user learns why the first frame waits.
    """
    from ..kernels.cache import TYPICAL_COMPILE_SECONDS, active_cache_dir

    stream = stream or sys.stderr

    def announce():
        print(f"fastdet: compiling kernels, once per machine: ~{TYPICAL_COMPILE_SECONDS} s "
              f"(cached in {active_cache_dir()})", file=stream, flush=True)

    timer = threading.Timer(COMPILE_NOTICE_AFTER, announce)
    timer.daemon = True
    if enabled:
        timer.start()
    try:
        yield
    finally:
        timer.cancel()
