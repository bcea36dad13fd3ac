"""Small synthetic video files whose frames can be told apart after lossy compression."""

from __future__ import annotations

import io
import socket
import struct
import threading
import time
from fractions import Fraction

import av
import numpy as np

SIZE = (64, 48)


def numbered_frame(i, size=SIZE):
    """A frame whose number survives lossy compression (0 to 143).

    The left half's grey level is ``20 * (i // 12) + 10``, the right half's
    ``20 * (i % 12) + 10``.
    """
    frame = np.empty((size[1], size[0], 3), np.uint8)
    frame[:, : size[0] // 2] = 20 * (i // 12) + 10
    frame[:, size[0] // 2:] = 20 * (i % 12) + 10
    return frame


def frame_number(frame):
    half = frame.shape[1] // 2
    level = lambda part: int(round((float(part.mean()) - 10) / 20))  # noqa: E731
    # Stay clear of the edge between the halves, which compression blurs.
    return 12 * level(frame[:, : half - 4]) + level(frame[:, half + 4:])


def write_clip(path, frames, fps=12.0, size=SIZE, times=None, options=None):
    """An H.264 mp4 of ``numbered_frame(i)``; ``times`` (seconds) makes it variable-rate.

    Odd sizes are stored as yuv444p, the only way libx264 takes them.
    """
    rate = Fraction(fps).limit_denominator(100000)
    time_base = Fraction(1, 90000) if times is not None else 1 / rate
    with av.open(str(path), "w") as container:
        stream = container.add_stream("libx264", rate=rate,
                                      options=options or {"preset": "ultrafast"})
        odd = size[0] % 2 or size[1] % 2
        pix_fmt = "yuv444p" if odd else "yuv420p"
        stream.width, stream.height, stream.pix_fmt = size[0], size[1], pix_fmt
        stream.codec_context.time_base = time_base
        for i in range(frames):
            frame = av.VideoFrame.from_ndarray(numbered_frame(i, size), format="bgr24")
            frame = frame.reformat(format=pix_fmt)
            frame.pts = i if times is None else round(times[i] / time_base)
            frame.time_base = time_base
            container.mux(stream.encode(frame))
        container.mux(stream.encode(None))
    return path


def free_port(kind):
    """A port on 127.0.0.1 that nothing listens on now (``socket.SOCK_STREAM`` or ``SOCK_DGRAM``)."""
    with socket.socket(socket.AF_INET, kind) as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def mpegts_bytes(path, frames=None):
    """The video stream of ``path`` remuxed into MPEG-TS, in memory."""
    buffer = io.BytesIO()
    with av.open(str(path)) as source, av.open(buffer, "w", format="mpegts") as target:
        stream = source.streams.video[0]
        out = target.add_stream_from_template(stream)
        for count, packet in enumerate(source.demux(stream)):
            if packet.dts is None or (frames is not None and count >= frames):
                continue
            packet.stream = out
            target.mux(packet)
    return buffer.getvalue()


class UdpSender:
    """Sends MPEG-TS to 127.0.0.1 from a thread, repeating it until stopped (at most ``seconds``)."""

    def __init__(self, payload, port, seconds=8.0):
        self.payload, self.port, self.seconds = payload, port, seconds
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._send, daemon=True)

    def _send(self):
        deadline = time.monotonic() + self.seconds
        chunk = 7 * 188   # whole TS packets per datagram
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            while not self.stop.is_set() and time.monotonic() < deadline:
                for offset in range(0, len(self.payload), chunk):
                    if self.stop.is_set():
                        return
                    sock.sendto(self.payload[offset:offset + chunk], ("127.0.0.1", self.port))
                    if offset // chunk % 20 == 0:
                        time.sleep(0.002)   # about real time: the receiver's buffer keeps up

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc):
        self.stop.set()
        self.thread.join(5)


def top_level_boxes(path):
    """The ISO-BMFF boxes at the top of an MP4 file, in order."""
    data, boxes, offset = path.read_bytes(), [], 0
    while offset + 8 <= len(data):
        size, kind = struct.unpack(">I4s", data[offset:offset + 8])
        if size == 1:
            size = struct.unpack(">Q", data[offset + 8:offset + 16])[0]
        boxes.append(kind.decode("latin-1"))
        offset += size if size else len(data)
    return boxes


def record_sources(monkeypatch, module):
    """Make ``module.VideoSource`` keep every source it opens; returns the list they go to."""
    from fastdet.video.source import VideoSource

    sources = []

    class RecordedSource(VideoSource):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            sources.append(self)

    monkeypatch.setattr(module, "VideoSource", RecordedSource)
    return sources
