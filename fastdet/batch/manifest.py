"""``DIR/manifest.jsonl``: one record per video, what makes a re-run skip it.

Each line is a JSON object::

    {"relative": "day1/clip.mp4", "input": "/footage/day1/clip.mp4", "size": 801181,
     "mtime_ns": ..., "sha256": "...", "model_sha256": "...", "config_sha256": "...",
     "status": "done", "frames": 38, "vehicles": 2, "detections": 74, "seconds": 1.9,
     "fps": 20.0, "segments": 1, "workers": ["tcp://127.0.0.1:40215"],
     "outputs": {"video": "day1/clip.mp4", ...}, ...}

with ``"status": "failed"`` and a one-line ``"reason"`` for a video that could
not be processed.  Records are appended (and flushed to disk) as videos
finish, so an interrupted batch keeps everything it completed; the last
record of a video wins, a torn last line is ignored, and the end of a run
rewrites the file with one record per video.

Lines are strict JSON (RFC 8259, :mod:`fastdet.files.strict_json`): a name
that is not UTF-8 (``relative``, ``input``, an output, a ``reason`` naming
it) is written as text with each odd byte as ``\\xff``, and its exact bytes
in base64 beside it in ``"<field>_bytes"`` (``"relative_bytes"``,
``"outputs": {"video_bytes": ...}``), present only for such a name; reading
puts the name back as Python's ``str`` of the bytes.  Lines written before
(``"\\udcff"`` escapes) read as they did.  A torn last line is ignored; so
is any line that is not a record as this module writes them (not UTF-8, not
JSON, a field missing or of another type: an edited or foreign file): its
video is then processed again.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

from ..files.atomic import atomic_path
from ..files.strict_json import dumps, restore_names

MANIFEST_NAME = "manifest.jsonl"
_CHUNK = 1 << 20
#: The statuses a record can have.
STATUSES = ("done", "failed")
#: Fields a re-run or the report reads as text, and as numbers (each may be absent).
_TEXT_FIELDS = ("input", "sha256", "model_sha256", "config_sha256", "reason")
_NUMBER_FIELDS = ("size", "mtime_ns", "frames", "vehicles", "detections", "seconds", "fps",
                  "segments")


def file_sha256(path):
    """SHA-256 of a file's content, read in 1 MiB chunks."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for chunk in iter(lambda: handle.read(_CHUNK), b""):
            digest.update(chunk)
    return digest.hexdigest()


def input_fingerprint(path, record=None):
    """``{"size", "mtime_ns", "sha256"}`` of an input file.

    The content hash of ``record`` (the video's last manifest record) is
    reused when the file's size and modification time are unchanged, as
    ``make`` and ``rsync`` do, so a re-run over terabytes of finished videos
    does not read them all again.
    """
    stat = os.stat(path)
    info = {"size": stat.st_size, "mtime_ns": stat.st_mtime_ns}
    if (record is not None and record.get("size") == info["size"]
            and record.get("mtime_ns") == info["mtime_ns"] and record.get("sha256")):
        info["sha256"] = record["sha256"]
    else:
        info["sha256"] = file_sha256(path)
    return info


def is_up_to_date(record, fingerprint, settings, out_dir):
    """Whether ``record`` says the video is done with these inputs, model and config.

    Parameters
    ----------
    record : dict or None
        The video's last manifest record.
    fingerprint : dict
        :func:`input_fingerprint` of the input now.
    settings : BatchSettings
    out_dir : Path
        Every output the record lists must still exist under it.
    """
    if record is None or record.get("status") != "done":
        return False
    if (record.get("sha256") != fingerprint["sha256"]
            or record.get("model_sha256") != settings.model_sha256
            or record.get("config_sha256") != settings.config_sha256):
        return False
    outputs = record.get("outputs") or {}
    return bool(outputs) and all((Path(out_dir) / rel).is_file() for rel in outputs.values())


def is_record(value):
    """Whether a parsed manifest line is a record as :class:`Manifest` writes them:
    a relative path and a status, and every field a re-run or the report reads
    of its type (text, numbers, outputs as relative paths)."""
    if not (isinstance(value, dict) and isinstance(value.get("relative"), str)
            and value.get("status") in STATUSES):
        return False
    outputs = value.get("outputs", {})
    if not (isinstance(outputs, dict) and all(isinstance(path, str) for path in outputs.values())):
        return False
    return (all(isinstance(value.get(key, ""), str) for key in _TEXT_FIELDS)
            and all(_is_number(value.get(key)) for key in _NUMBER_FIELDS))


def _is_number(value):
    return value is None or (isinstance(value, (int, float)) and not isinstance(value, bool))


class Manifest:
    """The records of an output folder, keyed by the videos' relative paths.

    Parameters
    ----------
    out_dir : str or Path
    """

    def __init__(self, out_dir):
        self.path = Path(out_dir) / MANIFEST_NAME
        self.records = {}
        if self.path.is_file():
            with open(self.path, "rb") as handle:
                for line in handle:
                    try:
                        record = restore_names(json.loads(line.decode("utf-8")))
                    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError):
                        continue          # a line torn by a crash, or not written by fastdet
                    if is_record(record):
                        self.records[record["relative"]] = record

    def get(self, relative):
        """The last record of a video, or ``None``."""
        return self.records.get(relative)

    def add(self, record):
        """Append a record and flush it to disk before returning."""
        # First in memory: an interrupt between the two must not let compact() drop it.
        self.records[record["relative"]] = record
        with open(self.path, "a+b") as handle:
            handle.seek(0, os.SEEK_END)
            if handle.tell() > 0:
                handle.seek(-1, os.SEEK_END)
                if handle.read(1) != b"\n":
                    handle.write(b"\n")   # end a torn line so this record stands alone
            handle.write(_line(record).encode("utf-8") + b"\n")
            handle.flush()
            os.fsync(handle.fileno())

    def compact(self):
        """Rewrite the file atomically with one record per video, sorted by path."""
        with atomic_path(self.path) as tmp, open(tmp, "w", encoding="utf-8") as handle:
            for relative in sorted(self.records):
                handle.write(_line(self.records[relative]) + "\n")


def _line(record):
    """A record as one line of strict JSON (:mod:`fastdet.files.strict_json`): a name that
    is not UTF-8 as text with ``\\xff`` plus its bytes in ``"<field>_bytes"``, and a
    non-finite number (none is expected: ``fps`` is ``None`` without a time) as null."""
    return dumps(record, nonfinite="null", sort_keys=True)
