"""Pictures: boxes drawn on frames."""

from __future__ import annotations

import cv2
import numpy as np

#: BGR colours cycled by track id.
_PALETTE = ((0, 0, 255), (0, 200, 0), (255, 0, 0), (0, 200, 255), (255, 0, 255),
            (255, 255, 0), (0, 128, 255), (128, 0, 255))


def draw_detections(frame, detections, thickness=3):
    """Draw boxes (and track ids when present) on a copy of a BGR frame.

    Parameters
    ----------
    frame : ndarray of uint8, shape (H, W, 3)
    detections : Detections
    thickness : int

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)
    """
    canvas = frame.copy()
    draw_detections_inplace(canvas, detections, thickness)
    return canvas


def draw_detections_inplace(canvas, detections, thickness=3):
    """Like :func:`draw_detections`, drawing on ``canvas`` itself."""
    for i, (x1, y1, x2, y2) in enumerate(detections.xyxy.tolist()):
        track = None if detections.track_id is None else int(detections.track_id[i])
        colour = _PALETTE[(track if track is not None else 0) % len(_PALETTE)]
        cv2.rectangle(canvas, (x1, y1), (x2 - 1, y2 - 1), colour, thickness)
        label = f"#{track}" if track is not None else f"{detections.score[i]:.1f}"
        cv2.putText(canvas, label, (x1, max(y1 - 6, 12)), cv2.FONT_HERSHEY_SIMPLEX, 0.6, colour, 2,
                    cv2.LINE_AA)
    return canvas


def write_image(path, image):
    """Write an image atomically; the format follows ``path``'s suffix."""
    from .atomic import atomic_path
    from .errors import InputError

    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), np.ascontiguousarray(image)):
            raise InputError(f"cannot write image {path} (unsupported extension?)")
