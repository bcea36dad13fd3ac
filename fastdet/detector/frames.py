"""What a frame must be: BGR uint8 ``(H, W, 3)``, with grey and BGRA converted."""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import InputError


def check_frame(frame):
    """Raise :class:`~fastdet.errors.InputError` unless ``frame`` is one a detector takes.

    That is a uint8 numpy array of shape (H, W), (H, W, 1), (H, W, 3) or
    (H, W, 4), of any layout (strided, Fortran-order, read-only views are
    frames too).  Nothing is converted or copied.

    Raises
    ------
    InputError
        For anything else, saying what the frame is.
    """
    if not isinstance(frame, np.ndarray):
        raise InputError(f"a frame must be a numpy array, got {type(frame).__name__}")
    if frame.dtype != np.uint8:
        raise InputError(f"a frame must be uint8 (BGR, 0-255), got {frame.dtype}")
    if not (frame.ndim == 2 or (frame.ndim == 3 and frame.shape[2] in (1, 3, 4))):
        raise InputError(f"a frame must have shape (H, W), (H, W, 1), (H, W, 3) or (H, W, 4), "
                         f"got {frame.shape}")


def as_bgr_frame(frame):
    """Validate a frame and return it as a C-contiguous BGR uint8 (H, W, 3) array.

    Grey (H, W) or (H, W, 1) frames are replicated to three channels and BGRA
    (H, W, 4) frames drop their alpha channel.

    Raises
    ------
    InputError
        For anything that is not a uint8 image array of those shapes
        (:func:`check_frame`).
    """
    check_frame(frame)
    if frame.shape[:2].count(0):
        # No pixel (OpenCV refuses to convert it): an empty BGR frame, which has no boxes.
        return np.zeros(frame.shape[:2] + (3,), np.uint8)
    if frame.ndim == 2 or frame.shape[2] == 1:
        return cv2.cvtColor(np.ascontiguousarray(frame.reshape(frame.shape[:2])),
                            cv2.COLOR_GRAY2BGR)
    if frame.shape[2] == 4:
        return cv2.cvtColor(np.ascontiguousarray(frame), cv2.COLOR_BGRA2BGR)
    return np.ascontiguousarray(frame)
