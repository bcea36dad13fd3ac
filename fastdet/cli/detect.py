"""``fastdet detect IMAGE...``: one JSON line per image."""

from __future__ import annotations

import json
import time
from pathlib import Path

from ..errors import InputError
from ..files.atomic import output_folder, output_in_folder, refuse_overwriting_inputs, same_file
from ..files.images import read_image, write_image
from .common import (add_horizon_option, add_model_options, compile_notice, make_detector,
                     resolve_images_horizon)


def add_detect_parser(subparsers):
    """Register ``detect`` on the ``fastdet`` command's sub-parsers."""
    detect = subparsers.add_parser("detect",
                                   help="detect vehicles in images; one JSON line per image")
    detect.add_argument("images", nargs="+", metavar="IMAGE")
    detect.add_argument("--out-dir", metavar="D", help="also write each image with boxes drawn")
    add_model_options(detect)
    add_horizon_option(detect)
    detect.set_defaults(handler=cmd_detect)
    return detect


def cmd_detect(args):
    """Print ``{"image", "boxes", "ms"}`` per image; optionally write the drawn images.

    An ``"auto"`` horizon is one for all the images, as for a video's frames:
    they are taken to be one camera's (see :func:`resolve_images_horizon`).
    """
    from ..viz.draw import draw_detections

    detector = make_detector(args)
    targets = _drawn_image_paths(args.images, args.out_dir) if args.out_dir else None
    resolve_images_horizon(detector, args.images)
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
        if targets is not None:
            write_image(targets[index], draw_detections(image, detections))
            record["output"] = str(targets[index])
        print(json.dumps(record), flush=True)
    return 0


def _drawn_image_paths(images, out_dir):
    """Each image's own name inside ``out_dir`` (created), checked before any work.

    The names stay inside the folder whatever the inputs are called, and
    none may be an input: ``--out-dir`` the images' own folder would replace them.
    Nor may two images of one name from different folders share a drawing.
    """
    out_dir = output_folder(out_dir)
    targets = [output_in_folder(out_dir, Path(name).name) for name in images]
    drawn_from = {}
    for name, target in zip(images, targets):
        refuse_overwriting_inputs(target, images)
        first = drawn_from.setdefault(target, name)
        if first != name and same_file(name, [first]) is None:
            raise InputError(f"{first} and {name} would both be drawn to {target}: rename one "
                             "or detect them in separate runs")
    return targets
