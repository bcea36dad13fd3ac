"""Hard-negative mining: save the detector's false hits as training crops.

The loop is train -> mine -> retrain: run a model over annotated frames, keep
every hit window that overlaps no annotated vehicle (IoU below a threshold,
difficult vehicles included, so a car is never saved as a negative), save it
as a 64x64 crop, and train again with those crops as extra non-vehicles
(``fastdet train DATA --extra-negatives DIR``).

Sources are images (annotated under their file name) or videos (annotated as
``frame<N>``, N the 0-based frame index); only annotated frames are mined.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from .atomic import atomic_path
from .errors import InputError
from .evaluate import iou_matrix
from .features import WINDOW

VIDEO_SUFFIXES = {".mp4", ".avi", ".mov", ".mkv", ".m4v"}


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
    source = Path(source)
    if not source.is_file():
        raise InputError(f"mining source not found: {source}")
    if source.suffix.lower() in VIDEO_SUFFIXES:
        capture = cv2.VideoCapture(str(source))
        if not capture.isOpened():
            raise InputError(f"cannot open video {source}")
        try:
            index = 0
            while True:
                ok, frame = capture.read()
                if not ok:
                    break
                key = f"frame{index:04d}"
                if key in annotations:
                    yield key, frame
                index += 1
        finally:
            capture.release()
        return
    if source.name in annotations:
        frame = cv2.imread(str(source), cv2.IMREAD_COLOR)
        if frame is None:
            raise InputError(f"cannot read {source} as an image")
        yield source.name, frame


def mine(detector, sources, annotations, out_dir, max_iou=0.1):
    """Save every hit window that overlaps no annotated vehicle.

    Parameters
    ----------
    detector : fastdet.Detector
        Its ``search.decision_threshold`` decides what a hit is.
    sources : iterable of str or Path
        Images and/or videos.
    annotations : dict
        As returned by :func:`fastdet.evaluate.load_annotations`.
    out_dir : str or Path
        Folder for the crops (created); files are ``<source>_<key>_<n>.png``.
    max_iou : float
        A hit whose IoU with every annotated box is below this is a negative.

    Returns
    -------
    MiningResult
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    frames = hits_total = 0
    saved = []
    for source in sources:
        for key, frame in annotated_frames(source, annotations):
            frames += 1
            hits = detector.hits(frame)
            hits_total += len(hits.scores)
            truth = np.array([a["box"] for a in annotations[key]], dtype=np.float64).reshape(-1, 4)
            overlap = iou_matrix(hits.boxes, truth).max(axis=1) if len(truth) else \
                np.zeros(len(hits.scores))
            for n, box in enumerate(hits.boxes[overlap < max_iou]):
                x1, y1, x2, y2 = (int(v) for v in box)
                crop = cv2.resize(frame[y1:y2, x1:x2], (WINDOW, WINDOW),
                                  interpolation=cv2.INTER_AREA)
                path = out_dir / f"{Path(source).stem}_{key}_{n:03d}.png"
                with atomic_path(path) as tmp:
                    if not cv2.imwrite(str(tmp), crop):
                        raise InputError(f"cannot write {path}")
                saved.append(path)
    if frames == 0:
        raise InputError("no annotated frame found in the sources (videos are annotated as "
                         "'frame<N>', images by file name)")
    return MiningResult(frames, hits_total, saved)
