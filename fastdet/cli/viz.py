"""``fastdet viz``: pictures of the data, the features, the search and the detector.

Each sub-command writes one figure (PNG by default; the format follows
``--out``'s suffix) and prints its path.  The pictures themselves are drawn by
the modules of :mod:`fastdet.viz`; this module only parses, loads inputs and names outputs.

Registered in :mod:`fastdet.cli.app` with :func:`add_viz_parser`.
"""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError
from ..files.images import read_image
from .common import make_detector


def add_viz_parser(subparsers):
    """Add the ``viz`` command and its sub-commands to ``fastdet``'s sub-parsers.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        What ``ArgumentParser.add_subparsers`` returned for the top level.

    Returns
    -------
    argparse.ArgumentParser
        The ``viz`` parser.
    """
    viz = subparsers.add_parser(
        "viz", help="pictures of the data, features, search windows and detections (PNG)",
        description="Write one figure and print its path.  Needs matplotlib "
                    "(pip install 'fastdet[viz]').")
    pictures = viz.add_subparsers(dest="picture", required=True, metavar="PICTURE")

    samples = pictures.add_parser("samples", help="random vehicle and non-vehicle crops")
    samples.add_argument("data_dir", metavar="DATA_DIR",
                         help="folder with vehicles/ and non-vehicles/")
    samples.add_argument("--n", type=int, default=8, help="crops per class (default 8)")
    samples.add_argument("--seed", type=int, help="seed of the random choice (default: fresh)")
    _add_out_option(samples, "viz_samples_<folder>.png")
    samples.set_defaults(handler=cmd_viz_samples)

    hog = pictures.add_parser("hog", help="an image beside its HOG glyphs, per channel")
    hog.add_argument("image", metavar="IMAGE")
    _add_model_option(hog)
    _add_out_option(hog, "viz_hog_<stem>.png")
    hog.set_defaults(handler=cmd_viz_hog)

    features = pictures.add_parser(
        "features", help="a 64x64 crop's feature vector and each feature's share of its score")
    features.add_argument("image", metavar="IMAGE", help="a crop (resized to 64x64 if needed)")
    _add_model_option(features)
    _add_out_option(features, "viz_features_<stem>.png")
    features.set_defaults(handler=cmd_viz_features)

    windows = pictures.add_parser("windows", help="every search window of every scale")
    windows.add_argument("frame", metavar="FRAME")
    _add_model_option(windows)
    _add_config_option(windows)
    _add_out_option(windows, "viz_windows_<stem>.png")
    windows.set_defaults(handler=cmd_viz_windows)

    detect = pictures.add_parser(
        "detect", help="hit windows, heat map, components and final boxes of one frame")
    detect.add_argument("frame", metavar="FRAME")
    detect.add_argument("--annotations", metavar="A.json",
                        help="draw this frame's ground-truth boxes (looked up by file name) "
                             "and say of each detection what fastdet eval counts it as")
    _add_model_option(detect)
    _add_config_option(detect)
    _add_out_option(detect, "viz_detect_<stem>.png")
    detect.set_defaults(handler=cmd_viz_detect)
    return viz


def _add_model_option(parser):
    parser.add_argument("--model", metavar="M", help="model file (.npz); default: bundled model")


def _add_config_option(parser):
    parser.add_argument("--config", metavar="C", help="TOML config overriding built-in defaults")


def _add_out_option(parser, default):
    parser.add_argument("--out", metavar="PATH",
                        help=f"output figure (default: {default} in the current folder)")


def _output_path(args, default_name):
    """``--out`` or the default name in the current folder, checked before any work.

    The default name is built from an input's name: it stays in the current
    folder; and no output may replace one of the command's inputs.
    """
    from ..files.atomic import output_in_folder, refuse_overwriting_inputs
    from ..viz.figure import check_output_path

    out = Path(args.out) if args.out else output_in_folder(Path("."), default_name)
    refuse_overwriting_inputs(out, [getattr(args, name, None) for name in
                                    ("image", "frame", "annotations", "model", "config")])
    # The text as given: a trailing slash, which Path drops, names a folder.
    return check_output_path(args.out or out)


def _report(path):
    print(path, flush=True)
    return 0


# -- handlers ---------------------------------------------------------------
def cmd_viz_samples(args):
    """``fastdet viz samples``."""
    from ..training.dataset import list_dataset
    from ..viz.data_figures import samples_figure

    data_dir = Path(args.data_dir)
    if not data_dir.is_dir():
        raise InputError(f"data folder not found: {data_dir}")
    out = _output_path(args, f"viz_samples_{data_dir.resolve().name or 'data'}.png")
    dataset = list_dataset(data_dir)
    return _report(samples_figure(dataset, out, n=args.n, seed=args.seed))


def cmd_viz_hog(args):
    """``fastdet viz hog``."""
    from ..detector.model import load_model
    from ..viz.data_figures import hog_figure

    out = _output_path(args, f"viz_hog_{Path(args.image).stem}.png")
    image = read_image(args.image)
    return _report(hog_figure(image, load_model(args.model).options, out))


def cmd_viz_features(args):
    """``fastdet viz features``."""
    from ..detector.model import load_model
    from ..viz.data_figures import features_figure

    out = _output_path(args, f"viz_features_{Path(args.image).stem}.png")
    image = read_image(args.image)
    return _report(features_figure(image, load_model(args.model), out))


def cmd_viz_windows(args):
    """``fastdet viz windows``."""
    from ..viz.search_figures import windows_figure

    out = _output_path(args, f"viz_windows_{Path(args.frame).stem}.png")
    frame = read_image(args.frame)
    plans = make_detector(args).plans((frame.shape[1], frame.shape[0]))
    if not plans:
        raise InputError(f"{args.frame} ({frame.shape[1]}x{frame.shape[0]}) is smaller than "
                         "every search window")
    return _report(windows_figure(frame, plans, out))


def cmd_viz_detect(args):
    """``fastdet viz detect``."""
    from ..viz.search_figures import detect_figure

    out = _output_path(args, f"viz_detect_{Path(args.frame).stem}.png")
    frame = read_image(args.frame)
    ground_truth = verdicts = None
    if args.annotations:
        from ..evaluation.annotations import load_annotations

        annotations = load_annotations(args.annotations)
        name = Path(args.frame).name
        if name not in annotations:
            raise InputError(f"{args.annotations} has no entry for {name}")
        ground_truth = annotations[name]
        verdicts = _verdicts_against(ground_truth)
    return _report(detect_figure(frame, make_detector(args), out, ground_truth=ground_truth,
                                 verdicts=verdicts))


def _verdicts_against(objects):
    """``verdicts(boxes, scores)``: each box's verdict against the annotated ``objects``
    (:meth:`fastdet.evaluation.matching.ImageMatch.verdicts`, the rules of ``fastdet eval``)."""
    from ..evaluation.annotations import ground_truth_arrays
    from ..evaluation.matching import match_image

    gt_boxes, gt_difficult = ground_truth_arrays(objects)
    return lambda boxes, scores: match_image(boxes, scores, gt_boxes, gt_difficult).verdicts()
