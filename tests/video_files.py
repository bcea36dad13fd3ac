"""Small synthetic video files whose frames can be told apart after lossy compression."""

from __future__ import annotations

from fractions import Fraction

import av
import numpy as np

SIZE = (64, 48)


def numbered_frame(i, size=SIZE):
    """A frame whose mean grey level (20 * i + 10) survives lossy compression."""
    return np.full((size[1], size[0], 3), 20 * i + 10, np.uint8)


def frame_number(frame):
    return int(round((float(frame.mean()) - 10) / 20))


def write_clip(path, frames, fps=12.0, size=SIZE, times=None):
    """An H.264 mp4 of ``numbered_frame(i)``; ``times`` (seconds) makes it variable-rate."""
    rate = Fraction(fps).limit_denominator(100000)
    time_base = Fraction(1, 90000) if times is not None else 1 / rate
    with av.open(str(path), "w") as container:
        stream = container.add_stream("libx264", rate=rate, options={"preset": "ultrafast"})
        stream.width, stream.height, stream.pix_fmt = size[0], size[1], "yuv420p"
        stream.codec_context.time_base = time_base
        for i in range(frames):
            frame = av.VideoFrame.from_ndarray(numbered_frame(i, size), format="bgr24")
            frame = frame.reformat(format="yuv420p")
            frame.pts = i if times is None else round(times[i] / time_base)
            frame.time_base = time_base
            container.mux(stream.encode(frame))
        container.mux(stream.encode(None))
    return path
