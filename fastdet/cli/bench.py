"""``fastdet bench``: the command that times fastdet against its peers.

Prints markdown: the latency table (fastdet per thread count, the reference,
OpenCV's HOGDescriptor; ratios on the same frames), fastdet's stage split,
fastdet.hog against scikit-image, the physical floor, and with ``--scaling``
the scaling study (``--plot`` draws it).
"""

from __future__ import annotations

import os
import sys


def add_bench_parser(subparsers):
    """Register ``bench`` on the ``fastdet`` command's sub-parsers."""
    bench = subparsers.add_parser(
        "bench", help="per-frame latency of fastdet and its peers (markdown tables)",
        description="Time fastdet, the reference pipeline and OpenCV's HOGDescriptor on the "
                    "same frames of a video and print markdown tables.")
    bench.add_argument("--input", metavar="VIDEO",
                       help="video to time (default: the shared test video)")
    bench.add_argument("--video", action="store_true",
                       help="time the main job instead: whole `fastdet run` processes on a "
                            "1000-frame H.264 input (made once) per mode, against OpenCV's "
                            "single-thread decoding rate R of the same file")
    bench.add_argument("--long-run", action="store_true",
                       help="resident memory and open files of one `fastdet run` process "
                            "sampled every 1000 frames of a 10,000-frame input (made once; "
                            "--frames sets its length)")
    bench.add_argument("--frames", type=int, metavar="N",
                       help="use the first N frames (default: all; 10 for --scaling; "
                            "10000 for --long-run)")
    bench.add_argument("--threads", type=int, nargs="+", metavar="T",
                       help="thread counts to time fastdet with (default: 1 and all cores)")
    bench.add_argument("--size", metavar="WxH",
                       help=f"resize frames first, e.g. 1920x1080 ({MIN_SIDE}-{MAX_SIDE} "
                            "pixels a side)")
    bench.add_argument("--repeat", type=int, default=3,
                       help="timed calls per frame; the median is kept (default 3)")
    # The default lives in fastdet.bench.timing, which imports OpenCV and
    # Numba: too heavy for building the parser of every command.
    bench.add_argument("--turn-frames", type=int, metavar="K",
                       help="consecutive frames each pipeline (fastdet per thread count, "
                            "OpenCV) is timed on before the next one's turn, after one "
                            "untimed call (default 8)")
    bench.add_argument("--reference-frames", type=int, default=5, metavar="N",
                       help="frames to time the slow reference on (default 5; 0 skips it)")
    bench.add_argument("--no-opencv", action="store_true",
                       help="skip the OpenCV HOGDescriptor peer")
    bench.add_argument("--hog", action="store_true",
                       help="time fastdet.hog vs skimage.feature.hog at four frame sizes "
                            "(default: at the benchmark's frame size only)")
    bench.add_argument("--scaling", action="store_true",
                       help="also time fastdet vs frame size, number of scales and threads")
    bench.add_argument("--rounds", type=int,
                       help="round-robin passes over all settings; the median pass is kept "
                            "(default 5 for --scaling, 3 for --video)")
    bench.add_argument("--plot", metavar="PNG", help="draw the scaling study (implies --scaling)")
    bench.add_argument("--model", metavar="M", help="model file (default: bundled)")
    bench.add_argument("--config", metavar="C", help="TOML config")
    bench.set_defaults(handler=cmd_bench)
    return bench


#: Largest side ``--size`` takes (8K video is 7680 or 8192 wide): 100000x100000 tried to
#: allocate 30 GB per frame, and 16384x16384 failed in the labelling kernel.
MAX_SIDE = 8192
#: Smallest side ``--size`` takes: the 2x2-cell blocks of the HOG comparison need 16 pixels
#: (scikit-image refuses less; 7x5 ended in its ValueError as an internal error).
MIN_SIDE = 16


def parse_size(text):
    """``"1280x720"`` -> ``(1280, 720)``.

    Raises
    ------
    InputError
        For anything but ``WxH`` with each side from :data:`MIN_SIDE` to :data:`MAX_SIDE`.
    """
    from ..errors import InputError

    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise InputError(f"--size must look like 1280x720, got {text!r}") from None
    if width < 1 or height < 1:
        raise InputError(f"--size must be positive, got {text!r}")
    if not (MIN_SIDE <= width <= MAX_SIDE and MIN_SIDE <= height <= MAX_SIDE):
        raise InputError(f"--size sides must be {MIN_SIDE}-{MAX_SIDE} pixels, got {text!r}")
    return width, height


def check_frames_fit(video, count, size):
    """Refuse frames at ``size`` that would not fit in the memory available now.

    The benchmark decodes every frame it times before timing any (so that
    decoding is not timed); at a large ``--size`` they would be allocated one
    by one until the process is killed or OpenCV fails.

    Parameters
    ----------
    video : str or Path
    count : int or None
        ``--frames`` (``None``: every frame of the video).
    size : tuple of int
        ``(width, height)`` of the resized frames.

    Raises
    ------
    InputError
        When the frames would need more than the memory the system reports as
        available (``psutil``, as the batch layout reads it: Linux's MemAvailable).
    """
    import psutil

    from ..errors import InputError
    from ..video.source import VideoSource

    available = psutil.virtual_memory().available
    if count is None:
        with VideoSource(video) as source:
            count = source.frame_count or 1
    needed = count * size[0] * size[1] * 3
    if needed > available:
        raise InputError(f"--size {size[0]}x{size[1]}: {count} frames would take "
                         f"{needed / 2**30:.1f} GiB, more than the {available / 2**30:.1f} GiB "
                         "of memory available: use a smaller --size or fewer --frames")


def _machine_line():
    cores = os.cpu_count() or 1
    try:
        load = " / ".join(f"{v:.2f}" for v in os.getloadavg())
    except OSError:  # pragma: no cover - not on Linux
        load = "n/a"
    return f"{cores} cores, load average {load} (1/5/15 min) at start"


def cmd_bench(args):
    """Run the benchmark and print markdown tables; returns the exit code."""
    import numba

    from ..bench.floor import floor_estimate, format_floor
    from ..bench.frame_level import format_frame_level, frame_level_study, looped
    from ..bench.hog_compare import format_hog, hog_vs_skimage
    from ..bench.scaling import SIZES, format_scaling, scaling_study
    from ..bench.scaling_plot import plot_scaling
    from ..bench.latency import format_stages, format_table, format_threads, run_benchmark
    from ..bench.pipeline_processes import PipelineProcesses
    from ..bench.timing import TURN_FRAMES, read_frames
    from ..bench.two_cores import format_two_cores, two_core_ceiling
    from ..detector.config import load_config
    from ..detector.detector import Detector
    from ..detector.model import load_model
    from ..errors import InputError
    from ..files.shared_data import data_dir
    from ..video.stages import run_cores

    log = lambda line: print(line, file=sys.stderr, flush=True)  # noqa: E731
    for name in ("frames", "repeat", "rounds", "turn_frames"):
        value = getattr(args, name)
        if value is not None and value < 1:
            raise InputError(f"--{name.replace('_', '-')} must be at least 1, got {value}")
    # Before any frame is read: 0 was refused only after decoding the video, and 100000
    # started threads until "can't start new thread" (an internal error).
    for value in args.threads or ():
        run_cores(value)
    if args.reference_frames < 0:
        raise InputError(f"--reference-frames must be 0 (skip the reference) or more, got "
                         f"{args.reference_frames}")
    if args.plot is not None:
        # The scaling study takes minutes: a name it cannot be drawn to fails first.
        from ..files.atomic import check_writable
        from ..viz.figure import check_output_path

        check_output_path(args.plot)
        check_writable(args.plot)
    # Both time one `fastdet run` setting: options they would silently ignore are refused.
    if (args.video or args.long_run) and args.threads and len(args.threads) > 1:
        raise InputError(f"--{'video' if args.video else 'long-run'} takes one --threads "
                         f"count, got {len(args.threads)}")
    if args.video and args.frames is not None:
        from ..bench.video_run import LOOPED_FRAMES

        raise InputError(f"--frames does not apply to --video (its input is made once, "
                         f"{LOOPED_FRAMES} frames long)")
    if args.video:
        return _video_benchmark(args, log)
    if args.long_run:
        return _long_run(args, log)
    scaling = args.scaling or bool(args.plot)
    rounds = args.rounds or 5
    video = args.input or data_dir() / "test_video.mp4"
    size = parse_size(args.size) if args.size else None
    threads = args.threads or sorted({1, numba.config.NUMBA_NUM_THREADS})
    model = load_model(args.model)
    config = load_config(args.config)
    if size is not None:
        check_frames_fit(video, args.frames, size)
    print(f"machine: {_machine_line()}")
    frames = read_frames(video, args.frames, size)
    frame_size = (frames[0].shape[1], frames[0].shape[0])
    if not Detector(model=model, config=config, threads=1).plans(frame_size):
        # Nothing to time (and the physical floor divided by zero: an internal error).
        raise InputError(f"{video} at {frame_size[0]}x{frame_size[1]} is smaller than every "
                         "search window: use a larger --size")
    print(f"frames: {len(frames)} of {video} at {frame_size[0]}x{frame_size[1]}; "
          f"model: {args.model or 'bundled default'}")

    run = run_benchmark(frames, threads=threads, repeat=args.repeat,
                        reference_frames=args.reference_frames, opencv=not args.no_opencv,
                        model=model, config=config, log=log,
                        turn_frames=args.turn_frames or TURN_FRAMES)
    try:
        # Only known once a parallel kernel has run; it decides how threads behave under load.
        print(f"numba threading layer: {numba.threading_layer()}")
    except ValueError:
        pass
    print("\n## Latency per frame\n")
    print(format_table(run))
    if run.reference is not None:
        print(f"\nReference timed on frames {run.reference.frame_indices}; its ratios use "
              "every pipeline's times on those frames. OpenCV ratios use all frames.")
    if run.opencv:
        info = run.opencv["detector"]
        trained = "cached" if info["cached"] else f"trained in {info['train_seconds']} s"
        print(f"OpenCV {run.opencv['opencv_version']} (own environment): grey HOG, 1764 "
              f"features per window, linear SVM on {info['crops']} crops ({trained}); "
              f"fastdet scores {model.layout.length} features per window.")
        if run.opencv.get("cpu_features"):
            print(f"OpenCV's CPU dispatch: {run.opencv['cpu_features']} (* = built for "
                  "dispatch, ? = left out: levels above fastdet's kernels' build, so an "
                  "AVX2 build is compared with OpenCV's AVX2 code)")
    for note in run.notes:
        print(f"note: {note}")
    print("\n## fastdet stage split\n")
    print(format_stages(run.results))
    print("\n## fastdet threads (busy: colour conversion and scoring; ratio of medians)\n")
    print(format_threads(run.results))
    if max(threads) > 1:
        log("timing two copies of one kernel at once against one alone ...")
        print("\n" + format_two_cores(two_core_ceiling(frames[0])))
        pipeline_rounds = args.rounds or 3
        points = frame_level_study(
            frames, threads, pipeline_rounds, model, config, log=log,
            processes=lambda looped_frames, count: PipelineProcesses(
                looped_frames, count, args.model, args.config))
        passes = len(looped(frames))
        print(f"\n## The video pipeline: threads sharing each frame or scoring frames at once "
              f"(the {len(frames)} frames forward and back, {passes} a pass; default [track]; "
              f"median of {pipeline_rounds} round-robin passes)\n")
        print(format_frame_level(points))

    print("\n## fastdet.hog vs skimage.feature.hog\n")
    hog_sizes = SIZES if args.hog else (frame_size,)
    print(format_hog(hog_vs_skimage(frames[0], hog_sizes, log=log)))

    single = run.get("fastdet 1 thread")
    estimate = floor_estimate(run.plans, model, single.median_ms if single else None)
    print(f"\n## Physical floor ({frame_size[0]}x{frame_size[1]}, one core)\n")
    print(format_floor(estimate))

    if scaling:
        study_frames = frames[:args.frames or 10]
        points = scaling_study(study_frames, model=model, config=config,
                               threads=sorted({1, *threads}), rounds=rounds, log=log)
        print(f"\n## Scaling ({len(study_frames)} frames; median over {rounds} passes of "
              "the median ms per frame)\n")
        print(format_scaling(points))
        if args.plot:
            print(f"\nplot written to {plot_scaling(points, args.plot)}")
    return 0


def _long_run(args, log):
    """``fastdet bench --long-run``: memory and open files as a long run goes on."""
    from ..bench.long_run import LONG_RUN_FRAMES, format_long_run, long_input, long_run_profile
    from ..files.shared_data import data_dir

    print(f"machine: {_machine_line()}")
    frames = args.frames or LONG_RUN_FRAMES
    log(f"making the {frames}-frame input (once)...")
    video = long_input(args.input or data_dir() / "test_video.mp4", frames)
    options = ("--threads", str(args.threads[0])) if args.threads else ()
    samples = long_run_profile(video, options=options, log=log)
    print(f"\n## One `fastdet run` over {frames} frames (annotated H.264 + detections)\n")
    print(format_long_run(samples))
    return 0


def _video_benchmark(args, log):
    """``fastdet bench --video``: the main job's throughput per mode, against R."""
    from ..bench.video_run import format_video_benchmark, video_benchmark
    from ..files.shared_data import data_dir

    print(f"machine: {_machine_line()}")
    threads = args.threads[0] if args.threads else None
    benchmark = video_benchmark(args.input or data_dir() / "test_video.mp4",
                                rounds=args.rounds or 3, threads=threads, log=log)
    print("\n## fastdet run throughput\n")
    print(format_video_benchmark(benchmark, threads))
    return 0
