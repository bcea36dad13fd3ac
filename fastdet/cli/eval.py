"""``fastdet eval ANNOTATIONS.json IMAGE_DIR``: precision, recall, AP and IoU."""

from __future__ import annotations

import json
from pathlib import Path

from ..files.images import read_image
from .common import add_model_options, compile_notice, make_detector


def add_eval_parser(subparsers):
    """Register ``eval`` on the ``fastdet`` command's sub-parsers."""
    evaluate = subparsers.add_parser("eval",
                                     help="precision, recall, AP and IoU on annotated images")
    evaluate.add_argument("annotations", metavar="ANNOTATIONS.json")
    evaluate.add_argument("image_dir", metavar="IMAGE_DIR")
    evaluate.add_argument("--iou", type=float, default=0.5, help="match threshold (default 0.5)")
    evaluate.add_argument("--json", action="store_true", help="print the full report as JSON")
    evaluate.add_argument("--voc", action="store_true",
                          help="plain VOC rule: a detection on a difficult box counts only when "
                               "it matches it at --iou (default: also when half of it lies "
                               "inside one)")
    add_model_options(evaluate)
    evaluate.set_defaults(handler=cmd_eval)
    return evaluate


def cmd_eval(args):
    """Detect on every annotated image and print the report."""
    from ..evaluation.annotations import load_annotations
    from ..evaluation.matching import DIFFICULT_COVER
    from ..evaluation.metrics import evaluate

    annotations = load_annotations(args.annotations)
    detector = make_detector(args)
    image_dir = Path(args.image_dir)
    results = {}
    for index, name in enumerate(sorted(annotations)):
        image = read_image(image_dir / name)
        if index == 0:
            with compile_notice():
                detector.warm_up(image)
        detections = detector(image)
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
