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

import contextlib
import csv
import json
import math
from pathlib import Path

import numpy as np

from ..detector.detections import Detections
from ..errors import InputError
from ..files.atomic import StagedFile
from .standard_output import ReaderGone, writes_standard_output

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

    #: Whether the output is standard output and its reader closed it (``| head``).
    reader_gone = False

    def __init__(self, path, fmt=None):
        self.format = format_for(path, fmt)
        super().__init__(path)
        self.frames = 0
        self.boxes = 0
        self._handle = None
        try:
            with self._writing():
                # Line-buffered: a live run's detections can be followed as they come.
                self._handle = self.open("w", encoding="utf-8", newline="", buffering=1)
                if self.format == "csv":
                    self._handle.write(",".join(CSV_HEADER) + "\n")
        except BaseException:
            self.discard()
            raise

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
            # Strict JSON (RFC 8259) without fastdet.files.strict_json's walk of every
            # key and value: this line holds only fixed ASCII keys and numbers, and the
            # walk cost ~3 us a box on every frame (~27 us at 10 boxes).  Detections
            # holds finite scores only, so allow_nan=False is a guard that never fires.
            line = json.dumps({"frame": frame_index, "boxes": detections.to_list()},
                              separators=(", ", ": "), allow_nan=False)
            with self._writing():
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
        with self._writing():
            self._handle.writelines(rows)

    @contextlib.contextmanager
    def _writing(self):
        """:meth:`writing`, but a closed standard output raises :class:`ReaderGone`."""
        with self.writing():
            try:
                yield
            except BrokenPipeError:
                if not writes_standard_output(self.path):
                    raise
                self.reader_gone = True
                raise ReaderGone(self.path) from None

    def _finish(self):
        if self.reader_gone:
            self._abandon()
            return
        with self._writing():
            self._handle.close()

    def _abandon(self):
        if self._handle is not None:
            with contextlib.suppress(OSError):
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
        When the file is missing, not UTF-8 text, or malformed (naming the
        file and the line): a box is four integer pixel coordinates with
        ``x2 > x1`` and ``y2 > y1``, a score a finite number, a frame and a
        track id integers.
    """
    path = Path(path)
    fmt = format_for(path, fmt)
    if not path.is_file():
        raise InputError(f"detections file not found: {path}")
    try:
        with open(path, encoding="utf-8", newline="") as handle:
            lines = handle.read().splitlines()
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not a {fmt} detections file (not UTF-8 text at byte "
                         f"{exc.start})") from None
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc.strerror or exc}") from None
    start = 1 if fmt == "csv" else 0
    if fmt == "csv" and (not lines or tuple(lines[0].split(",")) != CSV_HEADER):
        raise InputError(f"{path}: expected the header {','.join(CSV_HEADER)}")
    rows = {}
    for number, line in enumerate(lines[start:], start + 1):
        if not line.strip():
            continue
        try:
            frame, items = _parse_line(line, fmt)
            rows.setdefault(frame, []).extend(items)
        except (ValueError, KeyError, TypeError, IndexError, OverflowError,
                RecursionError) as exc:
            raise InputError(f"{path}:{number}: not a {fmt} detections line "
                             f"({' '.join(str(exc).split())[:80]})") from None
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


def _parse_line(line, fmt):
    """``(frame, [(box, score, track), ...])`` of one line; ValueError etc. when malformed."""
    if fmt == "jsonl":
        record = json.loads(line)
        if not isinstance(record, dict) or not isinstance(record.get("boxes"), list):
            raise TypeError('expected {"frame": ..., "boxes": [...]}')
        boxes = record["boxes"]
        items = [(_box(box["box"]), _score(box["score"]), _track(box.get("track")))
                 for box in boxes]
        return _integer(record["frame"], "frame"), items
    fields = next(csv.reader([line]))
    if fmt == "csv":
        frame = _integer(fields[0], "frame")
        track = _track(fields[1] or None)
        box = _box(fields[2:6])
    else:
        frame, track = _integer(fields[0], "frame") - 1, _track(fields[1])
        left, top, width, height = (_pixel(v) for v in fields[2:6])
        box = _box([left, top, left + width, top + height])
    return frame, [(box, _score(fields[6]), track)]


def _integer(value, what):
    if isinstance(value, bool) or (isinstance(value, float) and not value.is_integer()):
        raise ValueError(f"{what} {value!r} is not an integer")
    return int(value)


def _pixel(value):
    """A MOTChallenge coordinate: any finite number, truncated to whole pixels."""
    number = float(value)
    if not math.isfinite(number):
        raise ValueError(f"coordinate {value!r} is not a finite number")
    return int(number)


def _box(values):
    if len(values) != 4:
        raise ValueError(f"a box has 4 coordinates, got {len(values)}")
    box = [_integer(v, "coordinate") for v in values]
    if not all(-2 ** 31 <= v < 2 ** 31 for v in box):
        raise ValueError("box coordinate out of range")
    if box[2] <= box[0] or box[3] <= box[1]:
        raise ValueError("a box needs x2 > x1 and y2 > y1")
    return box


def _score(value):
    if isinstance(value, bool):
        raise ValueError("score is not a number")
    score = float(value)
    if not math.isfinite(score) or abs(score) > 3e38:
        raise ValueError(f"score {value!r} is not a finite number")
    return score


def _track(value):
    if value is None:
        return None
    track = _integer(value, "track")
    if not -2 ** 63 <= track < 2 ** 63:
        raise ValueError("track id out of range")
    return track
