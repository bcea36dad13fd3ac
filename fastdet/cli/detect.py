"""``fastdet detect IMAGE...``: one JSON line per image."""

from __future__ import annotations

import json
import time
from pathlib import Path

from ..files.images import read_image, write_image
from .common import add_model_options, compile_notice, make_detector


def add_detect_parser(subparsers):
    """Register ``detect`` on the ``fastdet`` command's sub-parsers."""
    detect = subparsers.add_parser("detect",
                                   help="detect vehicles in images; one JSON line per image")
    detect.add_argument("images", nargs="+", metavar="IMAGE")
    detect.add_argument("--out-dir", metavar="D", help="also write each image with boxes drawn")
    add_model_options(detect)
    detect.set_defaults(handler=cmd_detect)
    return detect


def cmd_detect(args):
    """Print ``{"image", "boxes", "ms"}`` per image; optionally write the drawn images."""
    from ..viz.draw import draw_detections

    detector = make_detector(args)
    out_dir = Path(args.out_dir) if args.out_dir else None
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
    for index, name in enumerate(args.images):
        image = read_image(name)
        if index == 0:
            # Load the compiled kernels first, so "ms" is detection time only.
            with compile_notice():
                detector.warm_up(image)
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
