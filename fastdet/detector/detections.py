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
        xyxy = np.asarray(xyxy, dtype=np.int32).reshape(-1, 4)
        score = np.asarray(score, dtype=np.float32).reshape(-1)
        if score.shape[0] != xyxy.shape[0]:
            raise ValueError(f"{xyxy.shape[0]} boxes but {score.shape[0]} scores")
        if np.any(xyxy[:, 2] <= xyxy[:, 0]) or np.any(xyxy[:, 3] <= xyxy[:, 1]):
            raise ValueError("every box needs x2 > x1 and y2 > y1")
        if track_id is not None:
            track_id = np.asarray(track_id, dtype=np.int64).reshape(-1)
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
