"""Image files: read as BGR uint8 with a one-line error, write atomically."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from ..errors import InputError
from .atomic import atomic_path


def read_image(path):
    """Read an image file as BGR uint8, with a one-line error if impossible.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)

    Raises
    ------
    InputError
        When the file is missing or is not an image OpenCV can decode.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"image not found: {path}")
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise InputError(f"cannot read {path} as an image")
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
    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), np.ascontiguousarray(image)):
            raise InputError(f"cannot write image {path}: the encoder failed (disk full?)")
