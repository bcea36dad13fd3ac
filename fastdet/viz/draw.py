"""Drawing on BGR frames with OpenCV: boxes and the live debug view.

Cheap enough for every frame of a video (``fastdet run`` draws with these);
no matplotlib here, so the video path never imports it.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..detector.frames import as_bgr_frame
from ..errors import InputError

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


def _labelled_boxes(detections):
    """``(box, palette colour, label)`` of each detection."""
    for i, box in enumerate(detections.xyxy.tolist()):
        track = None if detections.track_id is None else int(detections.track_id[i])
        colour = _PALETTE[(track if track is not None else 0) % len(_PALETTE)]
        label = f"#{track}" if track is not None else f"{detections.score[i]:.1f}"
        yield box, colour, label


def draw_detections_inplace(canvas, detections, thickness=3):
    """Like :func:`draw_detections`, drawing on ``canvas`` itself."""
    for (x1, y1, x2, y2), colour, label in _labelled_boxes(detections):
        cv2.rectangle(canvas, (x1, y1), (x2 - 1, y2 - 1), colour, thickness)
        cv2.putText(canvas, label, (x1, max(y1 - 6, 12)), cv2.FONT_HERSHEY_SIMPLEX, 0.6, colour, 2,
                    cv2.LINE_AA)
    return canvas


def bgr_to_yuv(colour, bt709=False):
    """Limited-range ``(Y, U, V)`` of a BGR colour, by the BT.709 or BT.601 matrix."""
    blue, green, red = (c / 255.0 for c in colour)
    kr, kb = (0.2126, 0.0722) if bt709 else (0.299, 0.114)
    luma = kr * red + (1 - kr - kb) * green + kb * blue
    return (int(round(16 + 219 * luma)), int(round(128 + 224 * (blue - luma) / (2 - 2 * kb))),
            int(round(128 + 224 * (red - luma) / (2 - 2 * kr))))


def draw_detections_yuv420(luma, u, v, detections, bt709=False, thickness=3):
    """Draw boxes and labels on the planes of a yuv420p frame, in place.

    The same picture as :func:`draw_detections_inplace` on the BGR frame, drawn
    without converting the frame: luma at full resolution, chroma at half.

    Parameters
    ----------
    luma : ndarray of uint8, shape (H, W)
    u, v : ndarray of uint8, shape (ceil(H / 2), ceil(W / 2))
    detections : Detections
    bt709 : bool
        Colours by the BT.709 matrix (HD video) instead of BT.601.
    thickness : int
    """
    # Chroma lines two luma pixels per chroma pixel wide: as wide as the luma line.
    font, half = cv2.FONT_HERSHEY_SIMPLEX, max(1, thickness - 1)
    for (x1, y1, x2, y2), colour, label in _labelled_boxes(detections):
        y_value, u_value, v_value = bgr_to_yuv(colour, bt709)
        origin = (x1, max(y1 - 6, 12))
        cv2.rectangle(luma, (x1, y1), (x2 - 1, y2 - 1), y_value, thickness)
        cv2.putText(luma, label, origin, font, 0.6, y_value, 2, cv2.LINE_AA)
        for plane, value in ((u, u_value), (v, v_value)):
            cv2.rectangle(plane, (x1 // 2, y1 // 2), ((x2 - 1) // 2, (y2 - 1) // 2), value, half)
            cv2.putText(plane, label, (origin[0] // 2, origin[1] // 2), font, 0.3, value, 1,
                        cv2.LINE_AA)


def debug_frame(frame, detections, heat, timings_ms, heat_max=None):
    """A frame annotated for watching the detector live.

    Draws the detections, an inset of the heat map in the top-right corner
    and the per-stage timings as text in the top-left corner.  OpenCV only,
    a few milliseconds per 1280x720 frame, so it can run on every frame.

    Parameters
    ----------
    frame : ndarray of uint8, shape (H, W, 3)
        BGR frame (not modified).
    detections : Detections
        Boxes to draw (with track ids when present).
    heat : ndarray of float, shape (h, w), or None
        Heat map to show in the inset, normally the full-frame one
        (:meth:`fastdet.detector.detector.Detector.heatmap`); ``None`` or an empty array
        shows an empty inset.
    timings_ms : mapping of str to float
        Stage name to milliseconds, printed in the given order.
    heat_max : float, optional
        Heat shown as the brightest colour.  Default: the map's own maximum;
        pass a constant (e.g. a few times the heat threshold) to stop the
        inset's brightness from changing with every frame's maximum.

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)
        A new annotated BGR frame.
    """

    canvas = as_bgr_frame(frame).copy()
    height, width = canvas.shape[:2]
    # Text and inset follow the frame size so a 640-pixel frame is not all caption.
    text_scale = max(0.35, 0.5 * width / 1280)
    draw_detections_inplace(canvas, detections, thickness=max(1, round(2 * width / 1280)))
    _draw_heat_inset(canvas, heat, heat_max, text_scale)
    _draw_timings(canvas, timings_ms, text_scale)
    return canvas


def _draw_heat_inset(canvas, heat, heat_max, text_scale):
    """Colour-mapped heat, a quarter of the frame's width, in the top-right corner."""
    height, width = canvas.shape[:2]
    heat = np.zeros((1, 1), np.float32) if heat is None or np.size(heat) == 0 else heat
    heat = np.asarray(heat, dtype=np.float32)
    if heat.ndim != 2:
        raise InputError(f"heat must be a 2-D array, got shape {heat.shape}")
    inset_w = max(16, width // 4)
    inset_h = max(9, min(height // 2, round(inset_w * heat.shape[0] / max(heat.shape[1], 1))))
    if inset_w + 8 > width or inset_h + 8 > height:
        return  # frame too small to hold an inset
    peak = float(heat.max()) if heat_max is None else float(heat_max)
    scaled = cv2.resize(heat, (inset_w, inset_h), interpolation=cv2.INTER_AREA)
    level = np.clip(scaled * (255.0 / peak if peak > 0 else 0.0), 0, 255).astype(np.uint8)
    x0, y0 = width - inset_w - 4, 4
    canvas[y0:y0 + inset_h, x0:x0 + inset_w] = cv2.applyColorMap(level, cv2.COLORMAP_INFERNO)
    cv2.rectangle(canvas, (x0 - 1, y0 - 1), (x0 + inset_w, y0 + inset_h), (255, 255, 255), 1)
    cv2.putText(canvas, f"heat (max {float(heat.max()):.1f})", (x0 + 4, y0 + inset_h - 6),
                cv2.FONT_HERSHEY_SIMPLEX, text_scale, (255, 255, 255), 1, cv2.LINE_AA)


def _draw_timings(canvas, timings_ms, text_scale):
    """Stage timings on a darkened box in the top-left corner, numbers right-aligned."""
    if not timings_ms:
        return
    font = cv2.FONT_HERSHEY_SIMPLEX
    lines = [(str(name), f"{float(ms):.1f} ms") for name, ms in timings_ms.items()]
    line_h = int(round(26 * text_scale / 0.5))
    name_w = max(cv2.getTextSize(name, font, text_scale, 1)[0][0] for name, _ in lines)
    value_w = max(cv2.getTextSize(value, font, text_scale, 1)[0][0] for _, value in lines)
    box_w, box_h = name_w + value_w + 30, line_h * len(lines) + 10
    box_w, box_h = min(box_w, canvas.shape[1]), min(box_h, canvas.shape[0])
    # Darken rather than paint over, so the road under the text stays visible.
    canvas[:box_h, :box_w] = (canvas[:box_h, :box_w] * 0.35).astype(np.uint8)
    for row, (name, value) in enumerate(lines):
        baseline = 5 + line_h * (row + 1) - line_h // 4
        cv2.putText(canvas, name, (8, baseline), font, text_scale, (255, 255, 255), 1, cv2.LINE_AA)
        value_x = box_w - 8 - cv2.getTextSize(value, font, text_scale, 1)[0][0]
        cv2.putText(canvas, value, (value_x, baseline), font, text_scale, (120, 255, 120), 1,
                    cv2.LINE_AA)
