"""Ground truth: annotation files of vehicle boxes, read and validated.

An annotation file is::

    {"images": {"test1.jpg": [{"box": [x1, y1, x2, y2], "label": "car",
                               "difficult": false, "id": 3}, ...], ...},
     "frames": {"development": ["frame0125", ...], "held_out": [...]}}

with video frames named ``frame<N>`` (N the 0-based frame index, any number
of digits).  Boxes marked ``difficult`` are neither required nor penalised
(see :mod:`fastdet.evaluation.matching`).  ``id`` (optional) is the vehicle's
identity, the same in every frame, which the tracking metrics need.  The
optional ``frames`` object names subsets of the images (*splits*): frames
tuned on are kept apart from the frames reported as held out.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..errors import InputError


def load_annotations(path):
    """Read and validate an annotation file.

    Parameters
    ----------
    path : str or Path
        JSON file of the form ``{"images": {name: [object, ...]}}`` where each
        object has ``"box": [x1, y1, x2, y2]`` (numbers, ``x2 > x1``,
        ``y2 > y1``) and optionally ``"label"`` (str, default ``"car"``),
        ``"difficult"`` (bool, default ``False``) and ``"id"`` (int).  Other
        top-level keys (such as ``"format"``, a description) are ignored.

    Returns
    -------
    dict of str to list of dict
        Image name to its objects, each normalised to
        ``{"box": [float x4], "label": str, "difficult": bool, "id": int or None}``.
        Within an image each id names one vehicle, and no two names are one
        video frame (``frame1`` and ``frame01``).

    Raises
    ------
    InputError
        With a one-line message naming the file and the first problem: the
        file is missing, is not JSON, or does not have the structure above.
    """
    path, data = _read(path)
    annotations = {}
    frames = {}
    for image_name, objects in data["images"].items():
        if not isinstance(objects, list):
            raise InputError(f"{path}: images[{image_name!r}] must be a list of objects")
        # "frame1" and "frame01" are one video frame: one of them would be
        # scored against the frame's detections and the other against none.
        number = frame_number(image_name)
        if number is not None and frames.setdefault(number, image_name) != image_name:
            raise InputError(f"{path}: images {frames[number]!r} and {image_name!r} are the "
                             f"same video frame ({number})")
        parsed = [_parse_object(obj, f"{path}: images[{image_name!r}][{index}]")
                  for index, obj in enumerate(objects)]
        # One vehicle, one box a frame: a repeated id made IDF1 exceed 1.
        ids = [obj["id"] for obj in parsed if obj["id"] is not None]
        repeated = sorted({vehicle for vehicle in ids if ids.count(vehicle) > 1})
        if repeated:
            raise InputError(f"{path}: images[{image_name!r}] has {ids.count(repeated[0])} "
                             f"vehicles with id {repeated[0]}; an id names one vehicle a frame")
        annotations[image_name] = parsed
    return annotations


def load_splits(path):
    """The named subsets of an annotation file's images (its ``"frames"`` object).

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    dict of str to list of str
        Split name (e.g. ``"development"``, ``"held_out"``) to image names,
        each an annotated image; empty when the file names no splits.

    Raises
    ------
    InputError
        When ``"frames"`` is not an object of lists of annotated image names.
    """
    path, data = _read(path)
    splits = data.get("frames", {})
    if not isinstance(splits, dict):
        raise InputError(f"{path}: \"frames\" must map split names to lists of images")
    for name, images in splits.items():
        if not isinstance(images, list) or not all(isinstance(i, str) for i in images):
            raise InputError(f"{path}: frames[{name!r}] must be a list of image names")
        missing = [image for image in images if image not in data["images"]]
        if missing:
            raise InputError(f"{path}: frames[{name!r}] names {len(missing)} image(s) with no "
                             f"annotations, e.g. {missing[0]!r}")
    return {name: list(images) for name, images in splits.items()}


def frame_number(name):
    """The 0-based frame index of a video frame's name ``frame<N>``, or ``None``.

    ``N`` is ASCII digits: ``str.isdigit`` also takes ``"²"``, which ``int``
    refuses (an internal error), and ``"٣"``, which it reads as 3.
    """
    digits = name[5:] if name.startswith("frame") else ""
    return int(digits) if digits.isascii() and digits.isdigit() else None


def select_split(annotations, splits, name, path=None):
    """The annotations of one split's images (all of them for ``name=None``).

    ``path``, the annotation file, is named in the error.

    Raises
    ------
    InputError
        When the file names no split ``name``.
    """
    if name is None:
        return annotations
    if name not in splits:
        known = ", ".join(sorted(splits)) or "none"
        where = "the annotations" if path is None else str(path)
        raise InputError(f"no split {name!r} in {where} (splits: {known})")
    return {image: annotations[image] for image in splits[name]}


def tracked_identities(annotations, path, split=None):
    """Whether the annotations carry identities for the tracking metrics.

    Every vehicle that is not ``difficult`` needs an ``id`` for them
    (difficult vehicles are left out of the tracking metrics, so they may
    go without one); without any ``id`` only the detection figures are
    reported.

    Parameters
    ----------
    annotations : dict
        As :func:`load_annotations` (or :func:`select_split`) returns them.
    path : str or Path
        The annotation file, for the message.
    split : str, optional
        The split they were selected by, for the message.

    Returns
    -------
    bool
        True when every non-difficult vehicle has an ``id`` (also when there
        are none), False when no vehicle has one.

    Raises
    ------
    InputError
        When some vehicles have an ``id`` and a non-difficult one has none:
        the tracking figures were silently dropped.
    """
    order = sorted(annotations, key=lambda name: (frame_number(name) is None,
                                                  frame_number(name) or 0, name))
    vehicles = [(name, index, obj) for name in order
                for index, obj in enumerate(annotations[name]) if not obj["difficult"]]
    lacking = [(name, index) for name, index, obj in vehicles if obj["id"] is None]
    if not lacking:
        return True
    if not any(obj["id"] is not None for objects in annotations.values() for obj in objects):
        return False
    name, index = lacking[0]
    within = "" if split is None else f" of split {split!r}"
    raise InputError(f"{path}: {len(vehicles) - len(lacking)} of {len(vehicles)} vehicles{within} "
                     f"that are not difficult have an \"id\" and images[{name!r}][{index}] has "
                     f"none: the tracking metrics need one on every such vehicle (or none on "
                     f"any, for the detection figures only)")


def _read(path):
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path} is a folder, not an annotation file")
    if not path.is_file():
        raise InputError(f"annotation file not found: {path}")
    try:
        with open(path, encoding="utf-8") as handle:
            data = json.load(handle, object_pairs_hook=_unique_keys)
    except _RepeatedKey as exc:
        raise InputError(f"{path}: {exc}") from None
    except (ValueError, RecursionError) as exc:
        # JSONDecodeError (a ValueError) says where; a plain ValueError is an
        # integer of more digits than Python converts, RecursionError nesting
        # too deep to parse.
        raise InputError(f"{path} is not valid JSON: {exc}") from None
    if not isinstance(data, dict) or not isinstance(data.get("images"), dict):
        raise InputError(f"{path} must hold a JSON object with an \"images\" object")
    return path, data


class _RepeatedKey(ValueError):
    """A key given twice in one JSON object."""


def _unique_keys(pairs):
    """A JSON object's pairs as a dict; a key given twice is an error.

    ``json`` keeps the last of them silently: an image named twice lost its
    first list of boxes, and a second ``"box"`` replaced the first.
    """
    data = {}
    for key, value in pairs:
        if key in data:
            raise _RepeatedKey(f"{key!r} is given twice in one JSON object")
        data[key] = value
    return data


def _parse_object(obj, where):
    if not isinstance(obj, dict):
        raise InputError(f"{where} must be an object with a \"box\"")
    box = obj.get("box")
    if not isinstance(box, list) or len(box) != 4 or not all(_is_coordinate(v) for v in box):
        raise InputError(f"{where}.box must be a list of 4 finite numbers of at most "
                         f"{MAX_COORDINATE:g} in size, got {box!r}")
    if not (box[2] > box[0] and box[3] > box[1]):
        raise InputError(f"{where}.box must have x2 > x1 and y2 > y1, got {box!r}")
    label = obj.get("label", "car")
    if not isinstance(label, str):
        raise InputError(f"{where}.label must be a string, got {label!r}")
    difficult = obj.get("difficult", False)
    if not isinstance(difficult, bool):
        raise InputError(f"{where}.difficult must be true or false, got {difficult!r}")
    identity = obj.get("id")
    if identity is not None and (isinstance(identity, bool) or not isinstance(identity, int)):
        raise InputError(f"{where}.id must be an integer, got {identity!r}")
    return {"box": [float(v) for v in box], "label": label, "difficult": difficult,
            "id": identity}


#: Largest coordinate of a box: far beyond any frame, yet small enough that areas
#: and overlaps stay finite (1e308 made them overflow, with NumPy's warnings).
MAX_COORDINATE = 1e7


def _is_coordinate(value):
    """A finite number of at most :data:`MAX_COORDINATE` in size (bool, an int
    subclass, is certainly a mistake)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    try:
        return math.isfinite(value) and abs(value) <= MAX_COORDINATE
    except OverflowError:  # an int too large for a float
        return False


def ground_truth_arrays(objects):
    """Boxes and difficult flags of one image's annotation objects.

    Parameters
    ----------
    objects : list of dict
        One image's entry of :func:`load_annotations`.

    Returns
    -------
    boxes : ndarray of float64, shape (M, 4)
    difficult : ndarray of bool, shape (M,)
    """
    boxes = np.array([obj["box"] for obj in objects], dtype=np.float64).reshape(-1, 4)
    difficult = np.array([bool(obj.get("difficult", False)) for obj in objects], dtype=bool)
    return boxes, difficult
