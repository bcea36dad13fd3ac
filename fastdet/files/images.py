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
        decode (its header claiming more pixels than OpenCV decodes
        included), or damaged (cut short, corrupt data).
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
    try:
        image, complaints = _decode(data)
    except cv2.error as exc:
        # OpenCV asserts, rather than returning None, on a header that claims more
        # pixels than it decodes (CV_IO_MAX_IMAGE_PIXELS, 2**30): a 40000x40000 PNG
        # of a few bytes was an internal error of every verb that reads images.
        reason = ("more pixels than OpenCV decodes" if "CV_IO_MAX_IMAGE_PIXELS" in str(exc)
                  else " ".join(str(exc).split())[-120:])
        raise InputError(f"cannot read {path} as an image ({reason})") from None
    damage = [line for line in complaints if any(word in line for word in _DAMAGE)]
    if image is None:
        detail = f" ({damage[0]})" if damage else ""
        raise InputError(f"cannot read {path} as an image{detail}")
    if damage:
        raise InputError(f"{path} is damaged: {damage[0]}")
    for line in complaints:
        log.info("%s: %s", path, line)
    return image


#: Formats that hold one channel only (OpenCV refuses a colour image for
#: them): a colour image is written to them in grey.
GREY_ONLY_SUFFIXES = (".pgm", ".pbm")


def write_image(path, image):
    """Write an image atomically; the format follows ``path``'s suffix.

    A colour image written to a format that holds only grey
    (:data:`GREY_ONLY_SUFFIXES`) is converted to grey first.

    Raises
    ------
    InputError
        When OpenCV cannot encode the suffix's format, or the file cannot be
        written (a full disk, a read-only folder).
    """
    suffix = Path(path).suffix
    # cv2.haveImageWriter looks only at the suffix, and it crashed the
    # process (a segmentation fault) on a name that is not valid UTF-8.
    if not suffix.isascii() or not cv2.haveImageWriter("image" + suffix):
        raise InputError(f"cannot write image {path}: OpenCV has no writer for "
                         f"{suffix or 'a name without a suffix'!r}")
    image = np.ascontiguousarray(image)
    if suffix.lower() in GREY_ONLY_SUFFIXES and image.ndim == 3 and image.shape[2] == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    # Encoded in memory and written by Python, so a full disk is an OSError
    # (named by atomic_path) rather than an encoder's silent failure.  What
    # the encoder says on stderr becomes part of the one-line error.
    with _NativeStderr() as complaints:
        try:
            encoded, data = cv2.imencode(suffix, image)
        except cv2.error:
            encoded = False
    if not encoded:
        reasons = [_encoder_reason(line) for line in complaints.text.splitlines() if line.strip()]
        detail = f" ({reasons[0]})" if reasons else ""
        raise InputError(f"cannot write image {path}: OpenCV could not encode it{detail}")
    with atomic_path(path) as tmp:
        tmp.write_bytes(data.tobytes())


def _encoder_reason(line):
    """The reason in one of OpenCV's log lines, without its location prefixes."""
    line = " ".join(line.split())
    if ") " in line and "error: (" in line:     # "... error: (-5:Bad argument) WHY in function 'f'"
        line = line.split("error: (", 1)[1].split(") ", 1)[1]
    elif "errorLogCallback " in line:
        line = line.split("errorLogCallback ", 1)[1]
    return line.split(" in function ")[0]
