"""``fastdet eval ANNOTATIONS.json IMAGE_DIR|VIDEO``: detection and tracking quality.

On a folder of images every annotated image is detected on its own.  On a
video the frames go through the video pipeline exactly as ``fastdet run``
sends them (``--every``, ``--track`` and the config's ``[track]`` section
apply), the annotated frames (``frame<N>``) are scored, and when their
vehicles carry identities (``"id"``) the tracking metrics of py-motmetrics
(MOTA, IDF1, ID switches, fragmentations) are reported too.
"""

from __future__ import annotations

import sys
from pathlib import Path

from ..errors import InputError
from ..files.images import read_image
from ..files.strict_json import dumps
from .common import (add_horizon_option, add_model_options, add_schedule_options,
                     compile_notice, make_detector, make_pipeline, resolve_images_horizon)


def add_eval_parser(subparsers):
    """Register ``eval`` on the ``fastdet`` command's sub-parsers."""
    evaluate = subparsers.add_parser(
        "eval", help="precision, recall, AP, IoU (and MOTA, IDF1 on videos) on annotated frames",
        description="Detect on every annotated image of IMAGE_DIR, or run the video pipeline "
                    "over VIDEO and score its annotated frames (frame<N>); annotations with "
                    "vehicle ids also give the tracking metrics.")
    evaluate.add_argument("annotations", metavar="ANNOTATIONS.json")
    evaluate.add_argument("source", metavar="IMAGE_DIR|VIDEO")
    evaluate.add_argument("--split", metavar="NAME",
                          help="only the images the annotation file's \"frames\" lists under "
                               "NAME (e.g. development, held_out)")
    evaluate.add_argument("--iou", type=float, default=0.5, help="match threshold (default 0.5)")
    evaluate.add_argument("--json", action="store_true", help="print the full report as JSON")
    evaluate.add_argument("--voc", action="store_true",
                          help="plain VOC rule: a detection on a difficult box counts only when "
                               "it matches it at --iou (default: also when half of it lies "
                               "inside one)")
    add_schedule_options(evaluate)   # videos only
    add_model_options(evaluate)
    add_horizon_option(evaluate)
    evaluate.set_defaults(handler=cmd_eval)
    return evaluate


def cmd_eval(args):
    """Detect (or track) on every annotated frame and print the report."""
    from ..evaluation.annotations import (load_annotations, load_splits, select_split,
                                          tracked_identities)
    from ..evaluation.matching import DIFFICULT_COVER
    from ..evaluation.metrics import evaluate

    if not 0 < args.iou <= 1:            # before any work; NaN too
        raise InputError(f"--iou must be in (0, 1], got {args.iou}")
    annotations = select_split(load_annotations(args.annotations), load_splits(args.annotations),
                               args.split, args.annotations)
    if not annotations:
        # Every figure would be n/a, exit 0: an empty file or split is a mistake.
        chosen = "" if args.split is None else f" in split {args.split!r}"
        raise InputError(f"{args.annotations}: no annotated image or frame{chosen}: nothing "
                         f"to evaluate")
    source = Path(args.source)
    cover = None if args.voc else DIFFICULT_COVER
    if source.is_dir():
        if args.every is not None or args.track:
            raise InputError("--every and --track apply to a video, not to a folder of images")
        results = _detect_images(make_detector(args), source, annotations)
        tracking = None
    elif source.is_file():
        # Before the run: ids on only some vehicles would drop the tracking figures.
        with_ids = tracked_identities(annotations, args.annotations, args.split)
        results, tracking = _track_video(args, source, annotations, cover, with_ids)
    else:
        raise InputError(f"no such folder or video: {source}")
    report = evaluate(results, annotations, iou_threshold=args.iou, difficult_cover=cover)
    if args.json:
        out = report.to_dict()
        if tracking is not None:
            out["tracking"] = tracking.to_dict()
        # A figure without a denominator (NaN, e.g. an AP gain without vehicles) is null.
        print(dumps(out, nonfinite="null"))
        return 0
    print(f"images {len(annotations)}  vehicles {report.n_gt}  "
          f"TP {report.tp}  FP {report.fp}  FN {report.fn}")
    shown = _figures(report.to_dict(per_image=False))
    print(f"precision {shown['precision']}  recall {shown['recall']}  "
          f"AP{int(args.iou * 100)} {shown['ap']}  mean IoU {shown['mean_iou']}  "
          f"IoU 10th percentile {shown['iou_p10']}")
    print(_errors_lines(report.errors, args.iou))
    if tracking is not None:
        shown = _figures(tracking.to_dict())
        print(f"MOTA {shown['mota']}  IDF1 {shown['idf1']}  "
              f"ID switches {tracking.id_switches}  fragmentations {tracking.fragmentations}  "
              f"MOTP (IoU) {shown['motp']}  vehicles {tracking.vehicles}")
    return 0


def _figures(summary):
    """A report's figures as printed: three decimals, ``n/a`` where undefined (``None``)."""
    return {name: "n/a" if value is None else f"{value:.3f}" if isinstance(value, float)
            else value for name, value in summary.items()}


def _errors_lines(errors, iou_threshold):
    """The error breakdown (:func:`fastdet.evaluation.metrics.error_summary`) as two lines."""
    from ..evaluation.error_kinds import NEAR_IOU

    false, misses, gains = errors["false_positives"], errors["misses"], errors["ap_gain"]
    described = {"duplicate": "duplicates",
                 "localisation": f"on a vehicle at IoU {NEAR_IOU:g}-{iou_threshold:g}",
                 "difficult": "on difficult vehicles", "background": "on background"}
    kinds = ", ".join(f"{false[kind]} {text}" for kind, text in described.items())
    gained = ", ".join(f"{kind} {gains[kind]:+.3f}" for kind in (*described, "missed"))
    return (f"false positives: {kinds}; misses: {misses['near']} with a false positive near, "
            f"{misses['missed']} without\nAP{int(iou_threshold * 100)} gained by fixing each "
            f"kind: {gained}")


def _detect_images(detector, image_dir, annotations):
    resolve_images_horizon(detector, [image_dir / name for name in sorted(annotations)])
    results = {}
    for index, name in enumerate(sorted(annotations)):
        image = read_image(image_dir / name)
        if index == 0:
            with compile_notice():
                detector.warm_up(image)
        detections = detector(image)
        results[name] = (detections.xyxy, detections.score)
    return results


def _track_video(args, video, annotations, cover, with_ids):
    """Detections of the annotated frames, and the tracking report when ``with_ids``."""
    from ..video.evaluate import track_annotated_frames
    from ..video.horizon import resolve_video_horizon
    from ..video.source import VideoSource

    pipeline = make_pipeline(args)
    with VideoSource(video) as source:
        first_frame = source.first_frame
        horizon = resolve_video_horizon(pipeline.detector, source)
    if horizon is not None:
        print(f"fastdet: {video}: {horizon.describe()}; searching at "
              f"{pipeline.detector.config.search.horizon:.3f}", file=sys.stderr)
    # The pipeline's kernels too (heat smoothing, tracking), as fastdet run warms up.
    warm_up = pipeline.warm_up if hasattr(pipeline.detector, "warm_up") else None
    if warm_up is not None:
        with compile_notice():
            warm_up(first_frame)
    tracked = track_annotated_frames(pipeline, video, annotations)
    results = {name: (d.xyxy, d.score) for name, d in tracked.items()}
    if not with_ids:
        return results, None
    from ..evaluation.mot import tracking_metrics

    tracks = {name: (d.xyxy, d.track_id, d.score) for name, d in tracked.items()}
    return results, tracking_metrics(tracks, annotations, args.iou, cover)
