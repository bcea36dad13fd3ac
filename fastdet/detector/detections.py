"""The one type that carries boxes from the detector to every writer."""

from __future__ import annotations

import numpy as np


class Detections:
    """Boxes found in one frame.

    Parameters
    ----------
    xyxy : array_like of int, shape (N, 4)
        ``[x1, y1, x2, y2]`` in pixels, ``x2``/``y2`` exclusive.
    score : array_like of float, shape (N,)
        Confidence of each box (the peak of the heat map inside it).
    track_id : array_like of int, shape (N,), optional
        Identity of each box across frames, when a tracker assigned one.
    """

    __slots__ = ("xyxy", "score", "track_id")

    def __init__(self, xyxy, score, track_id=None):
        xyxy = _whole_numbers(xyxy, np.int32, "box coordinates").reshape(-1, 4)
        score = np.asarray(score, dtype=np.float64).reshape(-1)
        if score.shape[0] != xyxy.shape[0]:
            raise ValueError(f"{xyxy.shape[0]} boxes but {score.shape[0]} scores")
        with np.errstate(over="ignore"):
            score = score.astype(np.float32)
        if not np.all(np.isfinite(score)):
            # A NaN or infinite score would be written as JSON no strict parser reads.
            raise ValueError("every score must be a finite number (as float32)")
        if np.any(xyxy[:, 2] <= xyxy[:, 0]) or np.any(xyxy[:, 3] <= xyxy[:, 1]):
            raise ValueError("every box needs x2 > x1 and y2 > y1")
        if track_id is not None:
            track_id = _whole_numbers(track_id, np.int64, "track ids").reshape(-1)
            if track_id.shape[0] != xyxy.shape[0]:
                raise ValueError(f"{xyxy.shape[0]} boxes but {track_id.shape[0]} track ids")
        self.xyxy = xyxy
        self.score = score
        self.track_id = track_id

    @classmethod
    def of_valid(cls, xyxy, score, track_id=None):
        """Detections from arrays known to be valid: int32 ``(N, 4)`` boxes with
        ``x2 > x1`` and ``y2 > y1``, float32 ``(N,)`` scores and, optionally,
        int64 ``(N,)`` ids -- the detector's and tracker's own, made every
        frame, for which the checks of the constructor would be repeated work
        with the GIL held.  Nothing is copied or checked.
        """
        detections = cls.__new__(cls)
        detections.xyxy = xyxy
        detections.score = score
        detections.track_id = track_id
        return detections

    @classmethod
    def empty(cls):
        """No boxes."""
        return cls(np.zeros((0, 4), np.int32), np.zeros(0, np.float32))

    def __len__(self):
        return self.xyxy.shape[0]

    def __repr__(self):
        return f"Detections({len(self)} boxes)"

    def to_list(self):
        """JSON-ready list: ``[{"box": [...], "score": s[, "track": id]}, ...]``."""
        items = []
        for i in range(len(self)):
            item = {"box": [int(v) for v in self.xyxy[i]], "score": round(float(self.score[i]), 4)}
            if self.track_id is not None:
                item["track"] = int(self.track_id[i])
            items.append(item)
        return items


def _whole_numbers(values, dtype, what):
    """``values`` as ``dtype``, refusing what the cast would change: fractions
    (1.5 would become 1), NaN and numbers outside the type's range (which wrap)."""
    values = np.asarray(values)
    if values.dtype == dtype:
        return values
    if values.size == 0:
        return values.astype(dtype)
    if values.dtype.kind == "b" or values.dtype.kind not in "iuf":
        raise ValueError(f"{what} must be integers, not {values.dtype}")
    limits = np.iinfo(dtype)
    if values.dtype.kind == "f":
        if not np.all(np.isfinite(values)) or np.any(values != np.round(values)):
            raise ValueError(f"{what} must be whole numbers")
    if values.min() < limits.min or values.max() > limits.max:
        raise ValueError(f"{what} must lie between {limits.min} and {limits.max}")
    return values.astype(dtype)
