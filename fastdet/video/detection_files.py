"""Detections files (JSON lines, CSV, MOTChallenge), written atomically, and read back.

Formats, for a frame ``i`` counted from 0 in the input video:

``jsonl``
    One line per frame, also for frames without boxes::

        {"frame": i, "boxes": [{"box": [x1, y1, x2, y2], "score": s, "track": id}, ...]}

``csv``
    A header ``frame,track,x1,y1,x2,y2,score`` and one row per box.

``mot``
    MOTChallenge text, one row per box:
    ``frame,id,bb_left,bb_top,bb_width,bb_height,conf,-1,-1,-1`` with
    frames counted from 1.

Boxes are ``[x1, y1, x2, y2]`` pixels with ``x2``/``y2`` exclusive, so the
MOT width is ``x2 - x1``.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from ..detector.detections import Detections
from ..errors import InputError
from ..files.atomic import StagedFile

FORMATS = ("jsonl", "csv", "mot")
#: Format chosen by a file suffix when none is given.
SUFFIX_FORMATS = {".jsonl": "jsonl", ".json": "jsonl", ".ndjson": "jsonl", ".csv": "csv",
                  ".txt": "mot", ".mot": "mot"}
CSV_HEADER = ("frame", "track", "x1", "y1", "x2", "y2", "score")


def format_for(path, fmt=None):
    """The detections format: ``fmt`` if given, else from ``path``'s suffix, else jsonl."""
    if fmt is None:
        return SUFFIX_FORMATS.get(Path(path).suffix.lower(), "jsonl")
    if fmt not in FORMATS:
        raise InputError(f"unknown detections format {fmt!r} (choose from {', '.join(FORMATS)})")
    return fmt


class DetectionWriter(StagedFile):
    """Writes the boxes of each frame to a detections file.

    Parameters
    ----------
    path : str or Path
    fmt : {'jsonl', 'csv', 'mot'}, optional
        Default: from the suffix (``.jsonl``/``.json``, ``.csv``,
        ``.txt``/``.mot``), else ``jsonl``.

    Examples
    --------
    >>> with DetectionWriter("dets.jsonl") as out:           # doctest: +SKIP
    ...     out.write(0, detections)
    """

    def __init__(self, path, fmt=None):
        self.format = format_for(path, fmt)
        super().__init__(path)
        self.frames = 0
        self.boxes = 0
        try:
            # Line-buffered: a live run's detections can be followed as they come.
            self._handle = open(self.temporary, "w", encoding="utf-8", newline="", buffering=1)
        except OSError as exc:
            self.discard()
            raise InputError(f"cannot write {self.path}: {exc.strerror or exc}") from None
        if self.format == "csv":
            self._handle.write(",".join(CSV_HEADER) + "\n")

    def write(self, frame_index, detections):
        """Record the detections of one frame.

        Parameters
        ----------
        frame_index : int
            Counted from 0 in the input video.
        detections : Detections
            Boxes, scores and (normally) track ids; without ids the jsonl
            lines leave ``track`` out, csv leaves it empty and mot writes -1.
        """
        frame_index = int(frame_index)
        self.frames += 1
        self.boxes += len(detections)
        if self.format == "jsonl":
            line = json.dumps({"frame": frame_index, "boxes": detections.to_list()},
                              separators=(", ", ": "))
            self._handle.write(line + "\n")
            return
        ids = detections.track_id
        rows = []
        for k, (x1, y1, x2, y2) in enumerate(detections.xyxy.tolist()):
            score = f"{float(detections.score[k]):.4f}"
            if self.format == "csv":
                track = "" if ids is None else str(int(ids[k]))
                rows.append(f"{frame_index},{track},{x1},{y1},{x2},{y2},{score}\n")
            else:
                track = -1 if ids is None else int(ids[k])
                rows.append(f"{frame_index + 1},{track},{x1},{y1},{x2 - x1},{y2 - y1},"
                            f"{score},-1,-1,-1\n")
        self._handle.writelines(rows)

    def _finish(self):
        self._handle.close()

    def _abandon(self):
        self._handle.close()


def read_detections(path, fmt=None):
    """Read a detections file back.

    Parameters
    ----------
    path : str or Path
    fmt : {'jsonl', 'csv', 'mot'}, optional
        Default: from the suffix, as :class:`DetectionWriter` chooses it.

    Returns
    -------
    dict of int to Detections
        By frame index counted from 0.  Frames of a jsonl file are all
        present; csv and mot files only list frames with boxes.

    Raises
    ------
    InputError
        When the file is missing or malformed (naming the line).
    """
    path = Path(path)
    fmt = format_for(path, fmt)
    if not path.is_file():
        raise InputError(f"detections file not found: {path}")
    rows = {}
    with open(path, encoding="utf-8", newline="") as handle:
        lines = handle.read().splitlines()
    start = 1 if fmt == "csv" else 0
    if fmt == "csv" and (not lines or tuple(lines[0].split(",")) != CSV_HEADER):
        raise InputError(f"{path}: expected the header {','.join(CSV_HEADER)}")
    for number, line in enumerate(lines[start:], start + 1):
        if not line.strip():
            continue
        try:
            if fmt == "jsonl":
                record = json.loads(line)
                items = rows.setdefault(int(record["frame"]), [])
                for box in record["boxes"]:
                    items.append((box["box"], box["score"], box.get("track")))
            else:
                fields = next(csv.reader([line]))
                if fmt == "csv":
                    frame, track = int(fields[0]), (int(fields[1]) if fields[1] else None)
                    box = [int(v) for v in fields[2:6]]
                    score = float(fields[6])
                else:
                    frame, track = int(fields[0]) - 1, int(fields[1])
                    left, top, width, height = (int(float(v)) for v in fields[2:6])
                    box = [left, top, left + width, top + height]
                    score = float(fields[6])
                rows.setdefault(frame, []).append((box, score, track))
        except (ValueError, KeyError, TypeError, IndexError, StopIteration) as exc:
            raise InputError(f"{path}:{number}: not a {fmt} detections line ({exc})") from None
    result = {}
    for frame, items in sorted(rows.items()):
        boxes = np.array([item[0] for item in items], dtype=np.int32).reshape(-1, 4)
        scores = np.array([item[1] for item in items], dtype=np.float32)
        tracks = [item[2] for item in items]
        ids = None if any(t is None for t in tracks) or not tracks else tracks
        if not tracks:
            ids = np.zeros(0, np.int64)
        result[frame] = Detections(boxes, scores, ids)
    return result
