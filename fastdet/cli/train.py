"""``fastdet train DATA_DIR``: train a model, or compare colour spaces and feature sets."""

from __future__ import annotations

import math
import os
from pathlib import Path

from ..detector.features import COLOR_CODES, FeatureOptions
from ..errors import InputError
from ..files.atomic import check_writable, refuse_overwriting_inputs
from ..kernels.blocks import NORM_CODES
from .common import log_to_stderr, message_stream

#: LinearSVC regularisation when neither --C nor --cv is given.
DEFAULT_C = 1e-3
#: Values of C that --cv searches.
DEFAULT_C_GRID = (1e-4, 3e-4, 1e-3, 3e-3)


def add_train_parser(subparsers):
    """Register ``train`` on the ``fastdet`` command's sub-parsers."""
    defaults = FeatureOptions()
    train = subparsers.add_parser("train",
                                  help="train a model on vehicles/ and non-vehicles/ crops")
    train.add_argument("data_dir", metavar="DATA_DIR")
    train.add_argument("--out", metavar="MODEL.npz", help="where to write the model")
    train.add_argument("--report", metavar="PNG", help="also draw the training report")
    train.add_argument("--compare", action="store_true",
                       help="train every colour space x feature set and print a table")
    train.add_argument("--plot", metavar="PNG", help="with --compare: bar chart of the table")
    # The feature options' defaults are the bundled model's; help shows them.
    train.add_argument("--color-space", default=defaults.color_space, choices=sorted(COLOR_CODES),
                       help="colour space of every feature (default %(default)s)")
    train.add_argument("--hog-channel", default=str(defaults.hog_channel),
                       choices=["all", "gray", "0", "1", "2"],
                       help="channels HOG is computed on (default %(default)s)")
    train.add_argument("--orientations", type=int, default=defaults.orientations,
                       help="HOG orientation bins (default %(default)s)")
    train.add_argument("--pixels-per-cell", type=int, default=defaults.pixels_per_cell,
                       help="HOG cell side (default %(default)s)")
    train.add_argument("--cells-per-block", type=int, default=defaults.cells_per_block,
                       help="HOG block side in cells (default %(default)s)")
    train.add_argument("--block-norm", default=defaults.block_norm, choices=sorted(NORM_CODES),
                       help="HOG block normalisation (default %(default)s)")
    train.add_argument("--spatial-size", type=int, default=defaults.spatial_size,
                       help="side of the spatial features, 0 disables them (default %(default)s)")
    train.add_argument("--hist-bins", type=int, default=defaults.hist_bins,
                       help="colour histogram bins, 0 disables them (default %(default)s)")
    train.add_argument("--no-hog", action="store_true", help="disable HOG features")
    train.add_argument("--C", type=float, nargs="+",
                       help=f"LinearSVC regularisation; several values (or --cv) are "
                            f"cross-validated on the leak-free folds (default {DEFAULT_C:g})")
    train.add_argument("--cv", action="store_true",
                       help=f"choose C from {list(DEFAULT_C_GRID)} by leak-free cross-validation")
    train.add_argument("--no-flip", action="store_true", help="no horizontal-flip augmentation")
    train.add_argument("--no-jitter", action="store_true",
                       help="no jittered (scaled, shifted) copy of each training crop")
    train.add_argument("--no-photometric", action="store_true",
                       help="keep the jittered copy's look (no brightness, contrast, colour, "
                            "blur, resolution or JPEG changes)")
    train.add_argument("--source-holdout", action="store_true",
                       help="also hold out each source (GTI, KITTI, Extras) in turn and report "
                            "its accuracy (one more fit per source)")
    train.add_argument("--folds", type=int, default=5, help="leak-free split: contiguous folds (default %(default)s)")
    train.add_argument("--extra-negatives", nargs="+", metavar="DIR",
                       help="more folders of non-vehicle crops")
    train.set_defaults(handler=cmd_train)
    return train


def cmd_train(args):
    """Train and save a model (or run the ``--compare`` study)."""
    from ..training.train import train

    _check_numbers(args)
    _refuse_contradictions(args)
    if args.compare:
        _check_plot(args)
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
    _check_outputs(args)
    if args.C:
        C = args.C[0] if len(args.C) == 1 and not args.cv else tuple(args.C)
    else:
        C = DEFAULT_C_GRID if args.cv else DEFAULT_C
    from ..training.augment import Photometric

    model, (test_scores, test_labels) = train(
        args.data_dir, options=options, C=C, flip=not args.no_flip, jitter=not args.no_jitter,
        photometric=None if args.no_photometric else Photometric(), n_folds=args.folds,
        extra_negatives=args.extra_negatives or (), return_test_scores=True,
        log=log_to_stderr, hold_out_sources=args.source_holdout)
    model.save(args.out)
    messages = message_stream(args.out, args.report)
    if args.report:
        from ..viz.training_figures import training_report_figure
        training_report_figure(model.report, test_scores, test_labels, args.report)
        print(f"training report written to {args.report}", file=messages)
    report = model.report
    print(f"feature length {report['feature_length']}  crops {report['crops']}  "
          f"train time {report['total_seconds']:.1f} s", file=messages)
    print(f"accuracy: random split {report['random_split']['accuracy']:.4f}  "
          f"leak-free split {report['leak_free_split']['accuracy']:.4f}", file=messages)
    for source, figures in (report["source_holdout"] or {}).items():
        print(f"source {source} held out: accuracy {figures['accuracy']:.4f} on "
              f"{figures['test_crops']} crops ({figures['vehicles']} vehicles)", file=messages)
    print(f"model written to {args.out}", file=messages)
    return 0


def _check_numbers(args):
    """Values the fit would reject only after minutes of feature extraction."""
    for C in args.C or ():
        if not (math.isfinite(C) and C > 0):    # NaN too
            raise InputError(f"--C must be a finite number above 0, got {C}")
    if args.folds < 2:
        raise InputError(f"--folds must be at least 2 (one fold is the test, the others are "
                         f"trained on), got {args.folds}")


def _refuse_contradictions(args):
    """Options the chosen mode would silently ignore: refused, so nobody waits for nothing.

    ``--compare`` trains one model per colour space and feature set and keeps
    none of them, so a model or report to write has no single model to come
    from; its table takes one C and no source hold-out or extra negatives.
    """
    if args.compare:
        ignored = [option for option, given in (
            ("--out", args.out is not None), ("--report", args.report is not None),
            ("--cv", args.cv), ("--source-holdout", args.source_holdout),
            ("--extra-negatives", bool(args.extra_negatives)),
            ("several --C values", bool(args.C) and len(args.C) > 1),
            # The study itself varies the colour space and the feature sets and splits
            # in 5 folds: these were accepted and ignored (--spatial-size 0 and
            # --hist-bins 0 became 32).  It fits no jittered or photometric copies,
            # so --no-jitter and --no-photometric say what it does anyway.
            ("--color-space", args.color_space != FeatureOptions().color_space),
            ("--hog-channel", args.hog_channel != str(FeatureOptions().hog_channel)),
            ("--no-hog", args.no_hog), ("--spatial-size 0", args.spatial_size == 0),
            ("--hist-bins 0", args.hist_bins == 0), ("--folds", args.folds != 5)) if given]
        if ignored:
            raise InputError(f"--compare writes no model and trains every colour space and "
                             f"feature set with one C, on its own split: {', '.join(ignored)} "
                             f"cannot be used with it")
    elif args.plot is not None:
        raise InputError("--plot draws the --compare table: add --compare, or use --report "
                         "for a training report")


def _check_plot(args):
    if args.plot is None:
        return
    from ..viz.figure import check_output_path

    refuse_overwriting_inputs(args.plot, _dataset_files(args))
    _refuse_inside_inputs(args.plot, _input_folders(args))
    check_output_path(args.plot)
    check_writable(args.plot)


def _input_folders(args):
    data = Path(args.data_dir)
    return [data / "vehicles", data / "non-vehicles", *(args.extra_negatives or ())]


def _dataset_files(args):
    # Listing is cheap next to training; a data set that cannot be listed is reported by train().
    from ..training.dataset import list_dataset

    try:
        return list_dataset(args.data_dir, args.extra_negatives or ()).paths
    except InputError:
        return []


def _refuse_inside_inputs(output, folders):
    """Refuse an output inside a training folder: it would replace a crop, or become one."""
    if output is None or str(output) == "-":
        return
    target = Path(os.path.realpath(output))
    for folder in folders:
        root = Path(os.path.realpath(folder))
        if target.is_relative_to(root):
            raise InputError(f"cannot write {output}: it is inside the training data folder "
                             f"{folder}; choose a name outside it")


def _check_outputs(args):
    """Every output name checked before training: none replaces an input or the other output."""
    outputs = [name for name in (args.out, args.report) if name is not None]
    inputs = _dataset_files(args)
    for output in outputs:
        refuse_overwriting_inputs(output, inputs)
        _refuse_inside_inputs(output, _input_folders(args))
        check_writable(output)
    if args.report is not None:
        from ..viz.figure import check_output_path

        check_output_path(args.report)
        if os.path.realpath(args.report) == os.path.realpath(args.out):
            raise InputError(f"--out and --report are both {args.out}: give them two names")


def _train_compare(args):
    from ..training.study import compare, format_markdown

    base = FeatureOptions(orientations=args.orientations, pixels_per_cell=args.pixels_per_cell,
                          cells_per_block=args.cells_per_block, block_norm=args.block_norm,
                          spatial_size=args.spatial_size or 32, hist_bins=args.hist_bins or 32)
    C = args.C[0] if args.C else DEFAULT_C
    rows = compare(args.data_dir, base, C=C, flip=not args.no_flip, log=log_to_stderr)
    print(format_markdown(rows))
    if args.plot:
        from ..viz.training_figures import study_figure
        print(f"plot written to {study_figure(rows, args.plot)}")
    return 0
