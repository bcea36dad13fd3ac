"""The ``fastdet`` command line: parse, call the library, print.

Every user-facing failure (a :class:`~fastdet.errors.FastdetError` or an
``OSError``) becomes one line ``fastdet: error: ...`` on stderr and exit code 2;
Ctrl-C exits with 130.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from .errors import FastdetError, InputError

EXIT_ERROR = 2
EXIT_INTERRUPTED = 130


def _add_model_options(parser):
    parser.add_argument("--model", metavar="M", help="model file (.npz); default: bundled model")
    parser.add_argument("--config", metavar="C", help="TOML config overriding built-in defaults")
    parser.add_argument("--threads", type=int, metavar="T",
                        help="threads per frame: scales are scored concurrently (default: "
                             "NUMBA_NUM_THREADS, all cores)")


def _detector(args):
    from .config import load_config
    from .detect import Detector

    return Detector(model=args.model, config=load_config(args.config), threads=args.threads)


def read_image(path):
    """Read an image file as BGR uint8, with a one-line error if impossible."""
    import cv2

    path = Path(path)
    if not path.is_file():
        raise InputError(f"image not found: {path}")
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise InputError(f"cannot read {path} as an image")
    return image


# -- detect -----------------------------------------------------------------
def cmd_detect(args):
    from .viz import draw_detections, write_image

    detector = _detector(args)
    out_dir = Path(args.out_dir) if args.out_dir else None
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
    for index, name in enumerate(args.images):
        image = read_image(name)
        if index == 0:
            # Load the compiled kernels first, so "ms" is detection time only.
            detector(image)
        start = time.perf_counter()
        detections = detector(image)
        elapsed_ms = (time.perf_counter() - start) * 1e3
        record = {"image": str(name), "boxes": detections.to_list(), "ms": round(elapsed_ms, 2)}
        if out_dir is not None:
            target = out_dir / Path(name).name
            write_image(target, draw_detections(image, detections))
            record["output"] = str(target)
        print(json.dumps(record), flush=True)
    return 0


# -- eval -------------------------------------------------------------------
def cmd_eval(args):
    from .evaluate import DIFFICULT_COVER, evaluate, load_annotations

    annotations = load_annotations(args.annotations)
    detector = _detector(args)
    image_dir = Path(args.image_dir)
    results = {}
    for name in sorted(annotations):
        detections = detector(read_image(image_dir / name))
        results[name] = (detections.xyxy, detections.score)
    cover = None if args.voc else DIFFICULT_COVER
    report = evaluate(results, annotations, iou_threshold=args.iou, difficult_cover=cover)
    if args.json:
        print(json.dumps(report.to_dict()))
    else:
        print(f"images {len(annotations)}  vehicles {report.n_gt}  "
              f"TP {report.tp}  FP {report.fp}  FN {report.fn}")
        print(f"precision {report.precision:.3f}  recall {report.recall:.3f}  "
              f"AP{int(args.iou * 100)} {report.ap:.3f}  mean IoU {report.mean_iou:.3f}")
    return 0


# -- train ------------------------------------------------------------------
def cmd_train(args):
    from .features import FeatureOptions
    from .train import train

    if args.compare:
        return _train_compare(args)
    channel = args.hog_channel
    options = FeatureOptions(
        color_space=args.color_space,
        hog_channel=int(channel) if channel.isdigit() else channel,
        orientations=args.orientations, pixels_per_cell=args.pixels_per_cell,
        cells_per_block=args.cells_per_block, block_norm=args.block_norm,
        spatial_size=args.spatial_size, hist_bins=args.hist_bins, use_hog=not args.no_hog)
    if args.out is None:
        raise InputError("fastdet train needs --out MODEL.npz (or --compare)")
    if args.C:
        C = args.C[0] if len(args.C) == 1 and not args.cv else tuple(args.C)
    else:
        C = DEFAULT_C_GRID if args.cv else DEFAULT_C
    model, (test_scores, test_labels) = train(
        args.data_dir, options=options, C=C, flip=not args.no_flip, jitter=not args.no_jitter,
        n_folds=args.folds,
        extra_negatives=args.extra_negatives or (), return_test_scores=True,
        log=lambda line: print(line, file=sys.stderr, flush=True))
    model.save(args.out)
    if args.report:
        from .viz import training_report_figure
        training_report_figure(model.report, test_scores, test_labels, args.report)
        print(f"training report written to {args.report}")
    report = model.report
    print(f"feature length {report['feature_length']}  crops {report['crops']}  "
          f"train time {report['total_seconds']:.1f} s")
    print(f"accuracy: random split {report['random_split']['accuracy']:.4f}  "
          f"leak-free split {report['leak_free_split']['accuracy']:.4f}")
    print(f"model written to {args.out}")
    return 0


# -- mine -------------------------------------------------------------------
def cmd_mine(args):
    from .evaluate import load_annotations
    from .mine import mine

    annotations = load_annotations(args.annotations)
    detector = _detector(args)
    result = mine(detector, args.sources, annotations, args.out, max_iou=args.max_iou)
    print(f"{len(result.saved)} hard negatives from {result.hits} hits in {result.frames} "
          f"annotated frames written to {args.out}")
    return 0


# -- tune -------------------------------------------------------------------
def cmd_tune(args):
    from .atomic import atomic_path
    from .config import load_config
    from .evaluate import load_annotations
    from .model import load_model
    from .tune import as_toml, format_results, tune

    annotations = load_annotations(args.annotations)
    results = tune(load_model(args.model), args.sources, annotations, load_config(args.config),
                   log=lambda line: print(line, file=sys.stderr))
    print(format_results(results, top=args.top))
    if args.out:
        with atomic_path(args.out) as tmp:
            Path(tmp).write_text(as_toml(results[0]))
        print(f"best thresholds written to {args.out}")
    return 0


def _train_compare(args):
    from .features import FeatureOptions
    from .study import compare, format_markdown, plot

    base = FeatureOptions(orientations=args.orientations, pixels_per_cell=args.pixels_per_cell,
                          cells_per_block=args.cells_per_block, block_norm=args.block_norm,
                          spatial_size=args.spatial_size or 32, hist_bins=args.hist_bins or 32)
    C = args.C[0] if args.C else DEFAULT_C
    rows = compare(args.data_dir, base, C=C, flip=not args.no_flip,
                   log=lambda line: print(line, file=sys.stderr, flush=True))
    print(format_markdown(rows))
    if args.plot:
        print(f"plot written to {plot(rows, args.plot)}")
    return 0


def build_parser():
    """The argument parser of the ``fastdet`` command."""
    from .features import COLOR_CODES, FeatureOptions
    from .kernels.blocks import NORM_CODES

    parser = argparse.ArgumentParser(
        prog="fastdet", description="Fast classical vehicle detection (HOG + linear SVM).")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    detect = sub.add_parser("detect", help="detect vehicles in images; one JSON line per image")
    detect.add_argument("images", nargs="+", metavar="IMAGE")
    detect.add_argument("--out-dir", metavar="D", help="also write each image with boxes drawn")
    _add_model_options(detect)
    detect.set_defaults(handler=cmd_detect)

    evaluate = sub.add_parser("eval", help="precision, recall, AP and IoU on annotated images")
    evaluate.add_argument("annotations", metavar="ANNOTATIONS.json")
    evaluate.add_argument("image_dir", metavar="IMAGE_DIR")
    evaluate.add_argument("--iou", type=float, default=0.5, help="match threshold (default 0.5)")
    evaluate.add_argument("--json", action="store_true", help="print the full report as JSON")
    evaluate.add_argument("--voc", action="store_true",
                          help="plain VOC rule: a detection on a difficult box counts only when "
                               "it matches it at --iou (default: also when half of it lies "
                               "inside one)")
    _add_model_options(evaluate)
    evaluate.set_defaults(handler=cmd_eval)

    defaults = FeatureOptions()
    train = sub.add_parser("train", help="train a model on vehicles/ and non-vehicles/ crops")
    train.add_argument("data_dir", metavar="DATA_DIR")
    train.add_argument("--out", metavar="MODEL.npz", help="where to write the model")
    train.add_argument("--report", metavar="PNG", help="also draw the training report")
    train.add_argument("--compare", action="store_true",
                       help="train every colour space x feature set and print a table")
    train.add_argument("--plot", metavar="PNG", help="with --compare: bar chart of the table")
    train.add_argument("--color-space", default=defaults.color_space, choices=sorted(COLOR_CODES))
    train.add_argument("--hog-channel", default=str(defaults.hog_channel),
                       choices=["all", "gray", "0", "1", "2"])
    train.add_argument("--orientations", type=int, default=defaults.orientations)
    train.add_argument("--pixels-per-cell", type=int, default=defaults.pixels_per_cell)
    train.add_argument("--cells-per-block", type=int, default=defaults.cells_per_block)
    train.add_argument("--block-norm", default=defaults.block_norm, choices=sorted(NORM_CODES))
    train.add_argument("--spatial-size", type=int, default=defaults.spatial_size,
                       help="0 disables spatial features")
    train.add_argument("--hist-bins", type=int, default=defaults.hist_bins,
                       help="0 disables colour histograms")
    train.add_argument("--no-hog", action="store_true", help="disable HOG features")
    train.add_argument("--C", type=float, nargs="+",
                       help=f"LinearSVC regularisation; several values (or --cv) are "
                            f"cross-validated on the leak-free folds (default {DEFAULT_C:g})")
    train.add_argument("--cv", action="store_true",
                       help=f"choose C from {list(DEFAULT_C_GRID)} by leak-free cross-validation")
    train.add_argument("--no-flip", action="store_true", help="no horizontal-flip augmentation")
    train.add_argument("--no-jitter", action="store_true",
                       help="no jittered (scaled, shifted) copy of each training crop")
    train.add_argument("--folds", type=int, default=5, help="leak-free split: contiguous folds")
    train.add_argument("--extra-negatives", nargs="+", metavar="DIR",
                       help="more folders of non-vehicle crops")
    train.set_defaults(handler=cmd_train)

    mine = sub.add_parser("mine", help="save false hits on annotated frames as negative crops")
    mine.add_argument("sources", nargs="+", metavar="SOURCE", help="images and/or videos")
    mine.add_argument("--annotations", required=True, metavar="A.json",
                      help="vehicle boxes: images by file name, video frames as frame<N>")
    mine.add_argument("--out", required=True, metavar="DIR", help="folder for the 64x64 crops")
    mine.add_argument("--max-iou", type=float, default=0.1,
                      help="a hit overlapping every vehicle less than this is a negative")
    _add_model_options(mine)
    mine.set_defaults(handler=cmd_mine)

    tune = sub.add_parser("tune", help="choose detection thresholds on annotated frames")
    tune.add_argument("sources", nargs="+", metavar="SOURCE", help="videos and/or images")
    tune.add_argument("--annotations", required=True, metavar="A.json")
    tune.add_argument("--out", metavar="CONFIG.toml", help="write the best thresholds as TOML")
    tune.add_argument("--top", type=int, default=10, help="rows of the table to print")
    tune.add_argument("--model", metavar="M", help="model file (default: bundled)")
    tune.add_argument("--config", metavar="C", help="TOML config with the scales and box filters")
    tune.set_defaults(handler=cmd_tune)

    from .commands_run import add_run_parser
    from .commands_viz import add_viz_parser
    add_run_parser(sub)
    add_viz_parser(sub)

    from .commands_bench import add_bench_parser
    add_bench_parser(sub)
    return parser


#: LinearSVC regularisation when neither --C nor --cv is given.
DEFAULT_C = 1e-3
#: Values of C that --cv searches.
DEFAULT_C_GRID = (1e-4, 3e-4, 1e-3, 3e-3)


def main(argv=None):
    """Entry point of the ``fastdet`` console script; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.handler(args)
    except KeyboardInterrupt:
        print("fastdet: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except (FastdetError, OSError) as exc:
        message = " ".join(str(exc).split()) or type(exc).__name__
        print(f"fastdet: error: {message}", file=sys.stderr)
        return EXIT_ERROR


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
