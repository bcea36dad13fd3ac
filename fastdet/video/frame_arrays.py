"""Decoded frames (``av.VideoFrame``) as numpy arrays: BGR, whole or a band of rows, and planes."""

from __future__ import annotations

import av
import numpy as np
from av.video.reformatter import VideoReformatter


class FrameConverter:
    """Decoded frames to BGR uint8 arrays, with its own swscale context (one per thread).

    ``to_bgr(frame, rows=(y0, y1))`` converts only those rows and returns a
    full-size array whose other rows are left uninitialised: the detector
    reads only the rows its scales search, so the rest of a frame need not
    be converted.  Converted rows are the same pixels as a full conversion.
    """

    def __init__(self):
        self._reformatter = VideoReformatter()

    def to_bgr(self, frame, rows=None):
        """BGR uint8 ``(height, width, 3)`` of an ``av.VideoFrame``.

        Parameters
        ----------
        frame : av.VideoFrame
        rows : tuple of int, optional
            ``(y0, y1)``: convert only these rows (of a yuv420p frame).
        """
        if rows is None or frame.format.name != "yuv420p":
            return self._reformatter.reformat(frame, format="bgr24", threads=1).to_ndarray()
        # Chroma rows cover two luma rows each: widen the band to even rows.
        y0, y1 = max(0, rows[0] - rows[0] % 2), min(frame.height, rows[1] + rows[1] % 2)
        image = np.empty((frame.height, frame.width, 3), np.uint8)
        if y1 <= y0:
            return image
        band = _yuv420p_rows(frame, y0, y1)
        image[y0:y1] = self._reformatter.reformat(band, format="bgr24", threads=1).to_ndarray()
        return image


def upright(frame):
    """``frame`` turned the way its display matrix says it is shown, or itself.

    Phones store a portrait video as landscape pictures plus a display
    matrix (rotation side data); players, FFmpeg's own tools and
    ``cv2.VideoCapture`` show the pictures turned by it.  Without turning
    them, the detector searched a sideways picture and the annotated copy,
    which has no such matrix, played sideways.  A turned frame is yuv420p
    (what the encoder takes anyway), with the same timestamp and colour tags;
    frames without a rotation cost nothing.
    """
    # PyAV gives the matrix's rotation counter-clockwise in degrees; np.rot90
    # turns counter-clockwise too.
    turns = round(getattr(frame, "rotation", 0) / 90) % 4
    if not turns:
        return frame
    source = frame
    if source.format.name != "yuv420p":
        source = source.reformat(format="yuv420p", dst_color_range="MPEG")
    width, height = (source.height, source.width) if turns % 2 else (source.width, source.height)
    turned = av.VideoFrame(width, height, "yuv420p")
    for index in range(3):
        # Odd sides: a chroma plane of ceil(h / 2) x ceil(w / 2) turns into ceil(w / 2) x
        # ceil(h / 2), which is the turned frame's.
        plane_view(turned, index)[:] = np.rot90(plane_view(source, index), turns)
    turned.pts, turned.time_base = frame.pts, frame.time_base
    turned.colorspace, turned.color_range = frame.colorspace, source.color_range
    return turned


def plane_view(frame, index):
    """Plane ``index`` of an ``av.VideoFrame`` as a ``(rows, width)`` uint8 view (no copy)."""
    plane = frame.planes[index]
    return np.frombuffer(plane, np.uint8).reshape(plane.height, plane.line_size)[:, :plane.width]


def _yuv420p_rows(frame, y0, y1):
    """Rows ``[y0, y1)`` of a yuv420p frame as a new frame with the same colour tags."""
    height = y1 - y0
    band = av.VideoFrame(frame.width, height, "yuv420p")
    c0, c1 = y0 // 2, (y1 + 1) // 2
    for index, (start, stop) in enumerate(((y0, y1), (c0, c1), (c0, c1))):
        source = plane_view(frame, index)[start:stop]
        target = plane_view(band, index)
        target[:source.shape[0]] = source
    band.colorspace, band.color_range = frame.colorspace, frame.color_range
    return band
