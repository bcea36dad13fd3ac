"""``fastdet detect IMAGE...``: one JSON line per image."""

from __future__ import annotations

import time
from pathlib import Path

from ..errors import InputError
from ..files.atomic import output_folder, output_in_folder, refuse_overwriting_inputs, same_file
from ..files.images import read_image, write_image
from ..files.strict_json import dumps
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

    Strict JSON (:mod:`fastdet.files.strict_json`): an image name that is not
    UTF-8 is printed with its odd bytes as ``\\xff``, and its bytes in base64
    in ``"image_bytes"`` (``"output_bytes"`` for the drawing).

    An ``"auto"`` horizon is one for all the images, as for a video's frames:
    they are taken to be one camera's (see :func:`resolve_images_horizon`).

    Every name is checked before the first image is searched (missing,
    a folder, not a regular file, empty, ``-``); an image that turns out to
    be damaged when it is decoded stops the run there, with the lines and
    drawings of the images before it complete.
    """
    from ..viz.draw import draw_detections

    _check_image_files(args.images)
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
        print(dumps(record), flush=True)
    return 0


def _check_image_files(images):
    """Refuse names no image can be read from, before any work.

    Images are read one at a time as they are searched, so a mistyped last
    name stopped the run after every other image had been searched (and
    drawn), and one ``-`` said only ``image not found: -``.
    """
    for name in images:
        if str(name) == "-":
            raise InputError("fastdet detect reads image files, not standard input ('-'): "
                             "give the images' paths")
        path = Path(name)
        if path.is_dir():
            raise InputError(f"{path} is a folder, not an image")
        if not path.exists():
            raise InputError(f"image not found: {path}")
        if not path.is_file():
            raise InputError(f"{path} is not a regular file: give image files")
        if path.stat().st_size == 0:
            raise InputError(f"cannot read {path} as an image: the file is empty")


def _drawn_image_paths(images, out_dir):
    """Each image's own name inside ``out_dir`` (created), checked before any work.

    The names stay inside the folder whatever the inputs are called, and
    none may be an input: ``--out-dir`` the images' own folder would replace them.
    Nor may two images of one name from different folders share a drawing,
    nor an image be drawn under a name whose suffix OpenCV cannot write.
    """
    import cv2

    for name in images:
        suffix = Path(name).suffix
        # OpenCV reads an image by its content, but writes by the name's suffix: "frame"
        # (no suffix) was searched, and the run failed only when its drawing was written.
        # (As in write_image: haveImageWriter crashed on a suffix that is not valid UTF-8.)
        if not suffix.isascii() or not cv2.haveImageWriter("image" + suffix):
            raise InputError(f"cannot draw {name} to {out_dir}: its drawing keeps its name, and "
                             f"OpenCV has no writer for {suffix or 'a name without a suffix'!r}"
                             f"; give it a suffix such as .jpg or .png")
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
