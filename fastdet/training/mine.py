"""Hard-negative mining: save the detector's false hits as training crops.

The loop is train -> mine -> retrain: run a model over annotated frames, keep
every hit window that overlaps no annotated vehicle -- IoU below a threshold
(0.1) and, so that a small window on a big car's tail light is not taken for
background, less than half of the window on any vehicle; difficult vehicles
count too, so a car is never saved as a negative -- save it as a 64x64 crop, and train again with those crops as extra non-vehicles
(``fastdet train DATA --extra-negatives DIR``).

Sources are images (annotated under their file name) or videos (annotated as
``frame<N>``, N the 0-based frame index); only annotated frames are mined.
Each source may come with annotations of its own (two videos both have a
``frame0010``), and an annotation file's split (``--split development``)
keeps held-out frames out of the training data.
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ..detector.features import WINDOW
from ..detector.geometry import iou_matrix
from ..errors import InputError
from ..evaluation.annotations import frame_number
from ..files.atomic import output_folder, output_in_folder, refuse_overwriting_inputs
from ..files.images import read_image, write_image
from ..video.source import VideoSource

VIDEO_SUFFIXES = {".mp4", ".avi", ".mov", ".mkv", ".m4v"}

#: What mining and tuning say when no source has an annotated frame: there is
#: nothing to learn from, and a tuning table over no frames reads as perfect.
NO_ANNOTATED_FRAME = ("no annotated frame found in the sources (videos are annotated as "
                      "'frame<N>', images by file name)")


@dataclass
class MiningResult:
    """What a mining run looked at and saved."""

    frames: int
    hits: int
    saved: list


def annotated_frames(source, annotations):
    """Yield ``(key, frame)`` for every annotated frame of an image or video.

    Parameters
    ----------
    source : str or Path
        An image or a video file.
    annotations : dict
        Image name or ``frame<N>`` -> list of annotation dicts.
    """
    source = check_source(source)
    if source.suffix.lower() in VIDEO_SUFFIXES:
        # Keys may have any number of digits (frame7 or frame0007).
        wanted = {frame_number(key): key for key in annotations
                  if frame_number(key) is not None}
        if not wanted:
            return
        last = max(wanted)
        read = 0
        with VideoSource(source) as video:
            # Frames not annotated are not converted, and mostly not decoded.
            for index, frame in enumerate(video.frames(needed=wanted.__contains__)):
                if frame is not None and index in wanted:
                    read += 1
                    yield wanted[index], frame
                if index >= last:
                    return
        # As fastdet eval says it (fastdet.video.evaluate): an annotated frame
        # past the end is a wrong file or wrong annotations, not a frame to skip.
        raise InputError(f"{source} ends before its annotated frame {wanted[last]} "
                         f"({read} of {len(wanted)} annotated frames read)")
    if source.name in annotations:
        yield source.name, read_image(source)


def check_source(source):
    """``source`` as a Path if it is a file to mine or tune on, else a one-line InputError."""
    source = Path(source)
    if source.is_dir():
        raise InputError(f"{source} is a folder: give its images (e.g. {source}/*.jpg) or a "
                         f"video file as sources")
    if not source.exists():
        raise InputError(f"source not found: {source}")
    if not source.is_file():
        raise InputError(f"{source} is not a regular file: give images or video files")
    return source


def check_sources(sources):
    """Check every source before the first frame is searched (a bad last one fails first)."""
    for source, _ in paired_sources(sources):
        check_source(source)


def paired_sources(sources, annotations=None):
    """``(source, annotations)`` pairs: each source with its own annotations or the shared ones.

    Parameters
    ----------
    sources : iterable
        Paths (annotated by ``annotations``) and/or ``(path, annotations)`` pairs.
    annotations : dict, optional
    """
    for source in sources:
        if isinstance(source, tuple):
            yield source
        else:
            yield source, annotations


def background_hits(boxes, vehicles, max_iou=0.1, max_cover=0.5):
    """Which hit boxes lie on no vehicle.

    Parameters
    ----------
    boxes : ndarray, shape (N, 4)
        Hit windows ``[x1, y1, x2, y2]``.
    vehicles : ndarray, shape (M, 4)
        Annotated vehicles (difficult ones included).
    max_iou : float
        Largest IoU with a vehicle a background hit may have.
    max_cover : float
        Largest fraction of its own area a background hit may share with a
        vehicle.

    Returns
    -------
    ndarray of bool, shape (N,)
    """
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    vehicles = np.asarray(vehicles, dtype=np.float64).reshape(-1, 4)
    if len(vehicles) == 0:
        return np.ones(len(boxes), dtype=bool)
    iou = iou_matrix(boxes, vehicles)
    ix = np.clip(np.minimum(boxes[:, None, 2], vehicles[None, :, 2])
                 - np.maximum(boxes[:, None, 0], vehicles[None, :, 0]), 0, None)
    iy = np.clip(np.minimum(boxes[:, None, 3], vehicles[None, :, 3])
                 - np.maximum(boxes[:, None, 1], vehicles[None, :, 1]), 0, None)
    area = ((boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1]))[:, None]
    cover = ix * iy / np.maximum(area, 1)
    return (iou.max(axis=1) < max_iou) & (cover.max(axis=1) < max_cover)


def _frame_keys(source, annotations):
    """The keys of ``source``'s frames that :func:`annotated_frames` would yield, unread."""
    if Path(source).suffix.lower() in VIDEO_SUFFIXES:
        return [key for key in annotations if frame_number(key) is not None]
    return [Path(source).name] if Path(source).name in annotations else []


def crop_prefixes(sources, annotations=None):
    """The name each source's crops start with: its stem, made unique within the run.

    Crops are ``<prefix>_<key>_<n>.png``.  The prefix is the source's stem,
    or ``<stem>-2``, ``<stem>-3`` ... for a later source whose crops would
    otherwise share names with an earlier one's: ``day1/clip.mp4`` and
    ``day2/clip.mp4`` both wrote their ``frame0010`` crops to the same
    files, the second replacing the first, and the count said more crops
    were written than there were.

    Parameters
    ----------
    sources : iterable
        As for :func:`mine`.
    annotations : dict, optional

    Returns
    -------
    list of str
        One prefix per source, in order.

    Raises
    ------
    InputError
        When one file is given twice (with annotated frames): its crops would
        be mined, and counted, twice.
    """
    taken = {}
    prefixes = []
    for number, (source, truth_of) in enumerate(paired_sources(sources, annotations)):
        keys = _frame_keys(source, truth_of or {})
        stem = prefix = Path(source).stem
        copy = 1
        while any(f"{prefix}_{key}" in taken for key in keys):
            earlier = next(taken[f"{prefix}_{key}"] for key in keys if f"{prefix}_{key}" in taken)
            if os.path.realpath(earlier) == os.path.realpath(source):
                raise InputError(f"{source} is given twice as a source: its frames would be "
                                 f"mined twice")
            copy += 1
            prefix = f"{stem}-{copy}"
        taken.update((f"{prefix}_{key}", source) for key in keys)
        prefixes.append(prefix)
    return prefixes


def _missing_folders(folder):
    """``folder`` and those of its parents that do not exist yet, deepest first."""
    missing = []
    folder = Path(folder)
    while not folder.exists() and folder != folder.parent:
        missing.append(folder)
        folder = folder.parent
    return missing


def mine(detector, sources, annotations, out_dir, max_iou=0.1):
    """Save every hit window that overlaps no annotated vehicle.

    Parameters
    ----------
    detector : fastdet.Detector
        Its ``search.decision_threshold`` decides what a hit is.
    sources : iterable
        Images and/or videos, each a path or a ``(path, annotations)`` pair.
    annotations : dict
        As returned by :func:`fastdet.evaluation.annotations.load_annotations`,
        for the sources given as bare paths.
    out_dir : str or Path
        Folder for the crops (created); files are ``<source>_<key>_<n>.png``,
        ``<source>`` the source's stem (``<stem>-2`` for a second source of
        that name, see :func:`crop_prefixes`).
    max_iou : float
        A hit whose IoU with every annotated box is below this is a negative
        (unless half of it or more lies on one of the boxes).

    Returns
    -------
    MiningResult

    Raises
    ------
    InputError
        Before any frame is searched: for a source that is missing or a
        folder, and for one given twice (:func:`crop_prefixes`); later, for
        a frame that cannot be read, an annotated video frame past the
        video's end, no annotated frame at all, or a crop that cannot be
        written.  Crops already saved are removed again.
    """
    # A list: the sources are gone through more than once, and a generator only once (it
    # was used up by the checks, and nothing was mined).
    sources = list(sources)
    check_sources(sources)
    prefixes = crop_prefixes(sources, annotations)
    inputs = [source for source, _ in paired_sources(sources)]
    created = _missing_folders(out_dir)
    out_dir = output_folder(out_dir, "--out")
    frames = hits_total = 0
    saved = []
    try:
        pairs = paired_sources(sources, annotations)
        for prefix, (source, truth_of) in zip(prefixes, pairs):
            for key, frame in annotated_frames(source, truth_of):
                frames += 1
                hits = detector.hits(frame)
                hits_total += len(hits.scores)
                truth = np.array([a["box"] for a in truth_of[key]],
                                 dtype=np.float64).reshape(-1, 4)
                negative = background_hits(hits.boxes, truth, max_iou)
                for n, box in enumerate(hits.boxes[negative]):
                    x1, y1, x2, y2 = (int(v) for v in box)
                    crop = cv2.resize(frame[y1:y2, x1:x2], (WINDOW, WINDOW),
                                      interpolation=cv2.INTER_AREA)
                    path = output_in_folder(out_dir, f"{prefix}_{key}_{n:03d}.png")
                    refuse_overwriting_inputs(path, inputs)
                    write_image(path, crop)
                    saved.append(path)
        if frames == 0:
            raise InputError(NO_ANNOTATED_FRAME)
    except BaseException:
        # A failed run leaves no half set of negatives behind, nor a folder it made for them.
        for path in saved:
            with contextlib.suppress(OSError):
                path.unlink()
        for folder in created:
            with contextlib.suppress(OSError):
                folder.rmdir()
        raise
    return MiningResult(frames, hits_total, saved)
