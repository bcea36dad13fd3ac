"""Image files: read as BGR uint8 with a one-line error, write atomically.

A damaged image is an error, not a silently half-grey frame: libjpeg decodes a
JPEG cut short to its full size, filling the missing rows, and only says so
on the process's standard error.  :func:`read_image` collects what the
decoders write there (libjpeg, libpng, OpenCV's log) while it decodes, so that
the user sees one line naming the file and the problem instead.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import tempfile
import threading
from pathlib import Path

import cv2
import numpy as np

from ..errors import InputError
from .atomic import atomic_path

log = logging.getLogger("fastdet.files")

#: What the decoders say about an image they could only partly decode.
_DAMAGE = ("Premature end of JPEG file", "Corrupt JPEG data", "libpng error", "CRC error",
           "Invalid", "invalid")

#: One decode at a time holds the process's standard error (file descriptor 2).
_STDERR_LOCK = threading.Lock()


class _NativeStderr(contextlib.AbstractContextManager):
    """Collect what C libraries write to file descriptor 2 meanwhile, in :attr:`text`.

    One file, created once and emptied before each use, receives it (one
    decode at a time: the descriptor belongs to the whole process).
    """

    _sink = None

    def __init__(self):
        self.text = ""
        self._saved = None

    def __enter__(self):
        _STDERR_LOCK.acquire()
        try:
            sys.stderr.flush()
            if _NativeStderr._sink is None:
                _NativeStderr._sink = tempfile.TemporaryFile()
            self._sink.seek(0)
            self._sink.truncate()
            self._saved = os.dup(2)
            os.dup2(self._sink.fileno(), 2)
        except (OSError, ValueError, AttributeError):  # no descriptor 2 to borrow
            self._saved = None
        return self

    def __exit__(self, *exc_info):
        try:
            if self._saved is not None:
                os.dup2(self._saved, 2)
                os.close(self._saved)
                self._sink.seek(0)
                self.text = self._sink.read().decode("utf-8", errors="replace")
        finally:
            _STDERR_LOCK.release()
        return False


def _decode(data):
    """``cv2.imdecode`` of ``data`` as BGR, and what the decoders complained about."""
    with _NativeStderr() as complaints:
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    lines = [" ".join(line.split()) for line in complaints.text.splitlines() if line.strip()]
    return image, lines


def read_image(path):
    """Read an image file as BGR uint8, with a one-line error if impossible.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)
        Grey, 16-bit and alpha images are converted (OpenCV's ``IMREAD_COLOR``).

    Raises
    ------
    InputError
        When the file is missing, a folder, empty, not an image OpenCV can
        decode, or damaged (cut short, corrupt data).
    """
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path} is a folder, not an image")
    if not path.is_file():
        raise InputError(f"image not found: {path}")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc.strerror or exc}") from None
    if not data:
        raise InputError(f"cannot read {path} as an image: the file is empty")
    image, complaints = _decode(data)
    damage = [line for line in complaints if any(word in line for word in _DAMAGE)]
    if image is None:
        detail = f" ({damage[0]})" if damage else ""
        raise InputError(f"cannot read {path} as an image{detail}")
    if damage:
        raise InputError(f"{path} is damaged: {damage[0]}")
    for line in complaints:
        log.info("%s: %s", path, line)
    return image


def write_image(path, image):
    """Write an image atomically; the format follows ``path``'s suffix.

    Raises
    ------
    InputError
        When OpenCV cannot encode the suffix's format, or the file cannot be
        written (a full disk, a read-only folder).
    """
    if not cv2.haveImageWriter(str(path)):
        raise InputError(f"cannot write image {path}: OpenCV has no writer for "
                         f"{Path(path).suffix or 'a name without a suffix'!r}")
    # Encoded in memory and written by Python, so a full disk is an OSError
    # (named by atomic_path) rather than an encoder's silent failure.
    encoded, data = cv2.imencode(Path(path).suffix, np.ascontiguousarray(image))
    if not encoded:
        raise InputError(f"cannot write image {path}: OpenCV could not encode it")
    with atomic_path(path) as tmp:
        tmp.write_bytes(data.tobytes())
