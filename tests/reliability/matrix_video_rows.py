"""The bad-input matrix's rows for ``fastdet run``: damaged videos, streams, outputs of every kind.

Inputs (:class:`VideoInputs`): a 10-frame clip, the shared test video cut
to its first 300 kB (4 whole frames) or with bytes garbled, a video whose
frames change size, one without frames, one with audio only, and an HTTP
server on 127.0.0.1 that serves the clip, answers 404, or closes the
connection half-way through a stream.  Network rows are bounded by
``--timeout``.

Outputs that are not regular files are written through in place: ``-``
and FIFOs get the detections file as it is, and the video as fragmented
MP4 (an index first needs the whole file); AVI cannot be streamed and is
refused.  Symbolic links are followed, except where fastdet builds the
name itself (the default output), where one is refused.
"""

from __future__ import annotations

import contextlib
import http.server
import io
import json
import os
import shutil
import socket
import stat
import threading
from fractions import Fraction

import av
import cv2
import numpy as np
import pytest
from matrix_checks import InputFolder, Row, fifo_reader, full_disk, read_only_out

from fastdet.video.detection_files import read_detections
from filesystems import private_device, private_stdout
from video_files import free_port, mpegts_bytes, numbered_frame, write_clip

CLIP_FRAMES = 10


class VideoInputs(InputFolder):
    """Good and bad videos, and an HTTP server on 127.0.0.1 (a context manager)."""

    def __init__(self, folder, data_dir):
        folder.mkdir()
        self.dir = folder
        real = (data_dir / "test_video.mp4").read_bytes()
        self.real = self.file("real.mp4", real)
        self.clip = write_clip(folder / "clip.mp4", CLIP_FRAMES, fps=12.0, size=(128, 96))
        self.file("empty.mp4", b"")
        self.file("random.mp4", np.random.default_rng(17).bytes(50_000))
        self.file("truncated.mp4", real[:300_000])
        self.file("garbled.mp4", garbled(real))
        (folder / "folder.mp4").mkdir()
        cv2.imwrite(str(folder / "still.png"), numbered_frame(3))
        zero = cv2.VideoWriter(str(folder / "zero.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 25.0,
                               (64, 48))
        zero.release()
        self.file("sizes.ts", size_changing_stream())
        audio_only(folder / "audio.mp4")
        self.track_config = self.file("track.toml", b"[track]\nevery_other = 2\n")
        os.symlink(self.clip, folder / "link.mp4")
        self._stream = mpegts_bytes(data_dir / "test_video.mp4")
        self._server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), self._handler())
        self._thread = threading.Thread(target=self._server.serve_forever, daemon=True)

    def url(self, name):
        return f"http://127.0.0.1:{self._server.server_address[1]}/{name}"

    def _handler(self):
        clip, stream = self.clip.read_bytes(), self._stream

        class Handler(http.server.BaseHTTPRequestHandler):
            def log_message(self, *args):
                pass

            def do_GET(self):
                if self.path == "/clip.mp4":
                    self._send(clip, len(clip))
                elif self.path == "/broken.ts":
                    # The length of the whole stream, then half of it and a closed connection.
                    self._send(stream[:len(stream) // 2], len(stream))
                else:
                    self.send_error(404)

            def _send(self, data, length):
                self.send_response(200)
                self.send_header("Content-Length", str(length))
                self.end_headers()
                self.wfile.write(data)
                self.close_connection = True

        return Handler

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._server.shutdown()
        self._server.server_close()


def garbled(data, seed=0):
    """``data`` with 20 runs of 200 random bytes: some frames decode with errors."""
    data = bytearray(data)
    rng = np.random.default_rng(seed)
    for offset in rng.integers(50_000, len(data) - 1000, 20):
        data[offset:offset + 200] = rng.bytes(200)
    return bytes(data)


def size_changing_stream():
    """MPEG-TS: 6 frames of 128x96, then 6 of 160x96 (two streams one after the other)."""
    parts = []
    for size in ((128, 96), (160, 96)):
        buffer = io.BytesIO()
        with av.open(buffer, "w", format="mpegts") as container:
            stream = container.add_stream("libx264", rate=12, options={"preset": "ultrafast"})
            stream.width, stream.height, stream.pix_fmt = *size, "yuv420p"
            for i in range(6):
                frame = av.VideoFrame.from_ndarray(numbered_frame(i, size), format="bgr24")
                frame = frame.reformat(format="yuv420p")
                frame.pts = i
                container.mux(stream.encode(frame))
            container.mux(stream.encode(None))
        parts.append(buffer.getvalue())
    return b"".join(parts)


def audio_only(path):
    """An MP4 holding one AAC stream of silence and no video."""
    with av.open(str(path), "w") as container:
        stream = container.add_stream("aac", rate=44100)
        for i in range(20):
            frame = av.AudioFrame.from_ndarray(np.zeros((1, 1024), np.float32), format="fltp",
                                               layout="mono")
            frame.sample_rate, frame.pts = 44100, i * 1024
            container.mux(stream.encode(frame))
        container.mux(stream.encode(None))


# -- what a good output holds ------------------------------------------------------------
def video_frames(source):
    """Frame indices of a video (a path or its bytes), from its timestamps; fails if damaged."""
    with av.open(io.BytesIO(source) if isinstance(source, bytes) else str(source)) as video:
        stream = video.streams.video[0]
        # Read while the container is open: a closed stream's fields are garbage.
        step = stream.time_base * (stream.average_rate or Fraction(12))
        frames = list(video.decode(stream))
    assert frames and not any(frame.is_corrupt for frame in frames)
    return [round((frame.pts - frames[0].pts) * step) for frame in frames]


def detection_frames(source, fmt="jsonl"):
    """Frame indices of a jsonl detections file (a path or its bytes)."""
    if isinstance(source, bytes):
        return [json.loads(line)["frame"] for line in source.decode().splitlines()]
    return sorted(read_detections(source, fmt))


def same_frames(video, detections, count=None):
    """Both outputs parse and hold the same frames (``count`` of them, from 0, when given)."""
    frames = detection_frames(detections)
    expected = list(range(count if count is not None else len(frames)))
    return frames == expected and video_frames(video) == expected


def still_there(path, kind):
    return kind(os.stat(path).st_mode)


def run(*args, quiet=True):
    return ["run", *map(str, args), *(["--quiet"] if quiet else [])]


def both(i, o, extra=()):
    """``--out`` and ``--detections`` in the row's folder."""
    return ["--out", o / "o.mp4", "--detections", o / "d.jsonl", *extra]


def outputs(i, o):
    return [o / "o.mp4", o / "d.jsonl"]


def refused(fault, video, problem, *, names=None, extra=(), **row):
    """A row whose input is refused before any output exists."""
    return Row("run", fault, lambda i, o: run(video(i), *both(i, o, extra)),
               names=lambda i, o: (names or video)(i), problem=problem, guarded=outputs, **row)


_FIFO = []
SUMMARY = r"^\d+ frames, "   # run's summary, on stderr when stdout holds an output
WARNING = r"^fastdet: warning: .*: input damaged: "

VIDEO_ROWS = [
    # ---- the input ------------------------------------------------------------------
    refused("video missing", lambda i: i.video / "missing.mp4", "not found"),
    refused("video empty", lambda i: i.video / "empty.mp4", "as a video"),
    refused("video random bytes", lambda i: i.video / "random.mp4", "as a video"),
    refused("video a folder", lambda i: i.video / "folder.mp4", "not a video file"),
    refused("video an image", lambda i: i.video / "still.png", "is an image"),
    refused("video without frames", lambda i: i.video / "zero.avi", "holds no frames"),
    refused("video with audio only", lambda i: i.video / "audio.mp4", "no video stream"),
    refused("video whose frames change size", lambda i: i.video / "sizes.ts",
            "frame size changes from 128x96 to 160x96 at frame 6"),
    Row("run", "video truncated (processed as far as it decodes)",
        lambda i, o: run(i.video / "truncated.mp4", *both(i, o)), code=0,
        messages=WARNING + "read 4 of 38 frames, decoding failed after frame 3",
        check=lambda i, o, out: same_frames(o / "o.mp4", o / "d.jsonl", 4)),
    refused("video truncated, --strict", lambda i: i.video / "truncated.mp4",
            "after frame 3", extra=["--strict"]),
    Row("run", "video with undecodable data (processed as far as it decodes)",
        lambda i, o: run(i.video / "garbled.mp4", *both(i, o)), code=0,
        messages=WARNING + r"read \d+ of 38 frames, .*decoded with errors",
        check=lambda i, o, out: same_frames(o / "o.mp4", o / "d.jsonl")),
    refused("video with undecodable data, --strict", lambda i: i.video / "garbled.mp4",
            "damaged|decoding failed", extra=["--strict"]),
    Row("run", "video is a symlink (followed)",
        lambda i, o: run(i.video / "link.mp4", *both(i, o)), code=0,
        check=lambda i, o, out: same_frames(o / "o.mp4", o / "d.jsonl", CLIP_FRAMES)),
    Row("run", "config with an unknown [track] key",
        lambda i, o: run(i.video.clip, *both(i, o, ["--config", i.video.track_config])),
        names=lambda i, o: i.video.track_config, problem="unknown key", guarded=outputs),
    # ---- streams (127.0.0.1, bounded by --timeout) ------------------------------------
    refused("stream: HTTP 404", lambda i: i.video.url("missing.mp4"), "404",
            extra=["--timeout", "5"]),
    refused("stream: connection refused",
            lambda i: f"http://127.0.0.1:{free_port(socket.SOCK_STREAM)}/clip.mp4",
            "refused", names=lambda i: "http://127.0.0.1:", extra=["--timeout", "5"]),
    refused("stream: UDP port nobody sends to",
            lambda i: f"udp://127.0.0.1:{free_port(socket.SOCK_DGRAM)}",
            "no data within the timeout", names=lambda i: "udp://127.0.0.1:",
            extra=["--timeout", "1"]),
    Row("run", "stream: server closes mid-stream (processed as far as it came)",
        lambda i, o: run(i.video.url("broken.ts"), *both(i, o, ["--timeout", "5"])), code=0,
        messages=WARNING + r"read \d+ frames, the input ends after frame \d+",
        check=lambda i, o, out: same_frames(o / "o.mp4", o / "d.jsonl")),
    refused("stream: server closes mid-stream, --strict", lambda i: i.video.url("broken.ts"),
            "reading failed after frame|is damaged", extra=["--timeout", "5", "--strict"]),
    Row("run", "stream: HTTP file", lambda i, o: run(i.video.url("clip.mp4"), *both(i, o)),
        code=0, check=lambda i, o, out: same_frames(o / "o.mp4", o / "d.jsonl", CLIP_FRAMES)),
]


def out_row(fault, target, code=2, problem="", names=None, **row):
    """A row writing the clip's annotated video to ``target(i, o)``."""
    return Row("run", fault, lambda i, o: run(i.video.clip, "--out", target(i, o)), code=code,
               names=names or (target if code else None), problem=problem, **row)


def dets_row(fault, target, code=2, problem="", names=None, **row):
    """A row writing the clip's detections to ``target(i, o)``."""
    return Row("run", fault, lambda i, o: run(i.video.clip, "--detections", target(i, o)),
               code=code, names=names or (target if code else None), problem=problem, **row)


VIDEO_ROWS += [
    # ---- outputs ----------------------------------------------------------------------
    out_row("--out in a read-only folder", lambda i, o: o / "o.mp4",
            problem="Read-only file system|Permission denied", guarded=lambda i, o: [o / "o.mp4"],
            setup=lambda i, o: read_only_out(o)),
    out_row("--out in a missing folder", lambda i, o: o / "missing" / "o.mp4",
            problem="No such file"),
    out_row("--out is a folder", lambda i, o: o, problem="directory"),
    out_row("--out with an unknown suffix", lambda i, o: o / "o.xyz",
            problem="unsupported suffix"),
    out_row("--out named only by its suffix (.mp4)", lambda i, o: o / ".mp4",
            problem="hidden file's name"),
    Row("run", "--out a container that cannot hold --codec (.mov, vp9)",
        lambda i, o: run(i.video.clip, "--out", o / "o.mov", "--codec", "vp9",
                         "--detections", o / "d.jsonl"),
        names=lambda i, o: o / "o.mov", problem="cannot hold vp9",
        guarded=lambda i, o: [o / "o.mov", o / "d.jsonl"]),
    Row("run", "--threads beyond 256",
        lambda i, o: run(i.video.clip, *both(i, o, ["--threads", "100000"])),
        names=lambda i, o: "100000", problem="--threads must be 1-256", guarded=outputs),
    Row("run", "--out on a full disk",
        lambda i, o: run(i.video.real, "--end", "8", "--out", o / "disk" / "o.mp4",
                         "--detections", o / "d.jsonl"),
        names=lambda i, o: o / "disk" / "o.mp4", problem="No space left",
        guarded=lambda i, o: [o / "disk" / "o.mp4", o / "disk" / "previous", o / "d.jsonl"],
        setup=lambda i, o: full_disk(o)),
    Row("run", "--detections on a full disk",
        lambda i, o: run(i.video.clip, "--detections", o / "disk" / "d.jsonl", "--out",
                         o / "o.mp4"),
        names=lambda i, o: o / "disk" / "d.jsonl", problem="No space left",
        guarded=lambda i, o: [o / "disk" / "d.jsonl", o / "disk" / "previous", o / "o.mp4"],
        setup=lambda i, o: full_disk(o, 16 * 1024 - 10)),
    out_row("--out is the input", lambda i, o: i.video.clip, problem="it is the input",
            guarded=lambda i, o: [i.video.clip]),
    out_row("--out is a symlink to the input", lambda i, o: i.video / "link.mp4",
            problem="it is the input", guarded=lambda i, o: [i.video.clip]),
    dets_row("--detections is the input", lambda i, o: i.video.clip, problem="it is the input",
             guarded=lambda i, o: [i.video.clip]),
    Row("run", "--out and --detections name the same file",
        lambda i, o: run(i.video.clip, "--out", o / "o.mp4", "--detections", o / "o.mp4"),
        names=lambda i, o: o / "o.mp4", problem="same file"),
    out_row("--out is a symlink (followed)", lambda i, o: o / "latest.mp4", code=0,
            setup=lambda i, o: contextlib.nullcontext(os.symlink(o / "real.mp4",
                                                                 o / "latest.mp4")),
            check=lambda i, o, out: (o / "latest.mp4").is_symlink()
            and video_frames(o / "real.mp4") == list(range(CLIP_FRAMES))),
    Row("run", "default output: a symlink stands under its name",
        lambda i, o: (shutil.copy(i.video.clip, o / "clip.mp4"),
                      os.symlink(o.parent / "outside.mp4", o / "clip_fastdet.mp4"),
                      run(o / "clip.mp4"))[-1],
        names=lambda i, o: o / "clip_fastdet.mp4", problem="symbolic link",
        guarded=lambda i, o: [o.parent / "outside.mp4"]),
    Row("run", "default output beside the input",
        lambda i, o: (shutil.copy(i.video.clip, o / "clip.mp4"), run(o / "clip.mp4"))[-1],
        code=0, check=lambda i, o, out: video_frames(o / "clip_fastdet.mp4")
        == list(range(CLIP_FRAMES))),
    # ---- outputs that are not regular files: written through, never replaced -----------
    dets_row("--detections - (stdout)", lambda i, o: "-", code=0, subprocess=True,
             messages=SUMMARY,
             check=lambda i, o, out: detection_frames(out) == list(range(CLIP_FRAMES))),
    dets_row("--detections /dev/stdout", lambda i, o: o / "stdout", code=0, subprocess=True,
             messages=SUMMARY, setup=lambda i, o: contextlib.nullcontext(private_stdout(o)),
             check=lambda i, o, out: detection_frames(out) == list(range(CLIP_FRAMES))
             and (o / "stdout").is_symlink()),
    dets_row("--detections is a FIFO", lambda i, o: o / "d.jsonl", code=0,
             setup=lambda i, o: fifo_reader(o / "d.jsonl", _FIFO),
             check=lambda i, o, out: still_there(o / "d.jsonl", stat.S_ISFIFO)
             and detection_frames(_FIFO[-1]) == list(range(CLIP_FRAMES))),
    dets_row("--detections a full device (/dev/full)", lambda i, o: i.device("full"),
             problem="No space left"),
    dets_row("--detections a null device (/dev/null)", lambda i, o: i.device("null"), code=0,
             check=lambda i, o, out: still_there(i.null, stat.S_ISCHR)),
    out_row("--out - (stdout): fragmented MP4", lambda i, o: "-", code=0, subprocess=True,
            messages=SUMMARY, check=lambda i, o, out: video_frames(out)
            == list(range(CLIP_FRAMES))),
    out_row("--out is a FIFO: fragmented MP4", lambda i, o: o / "o.mp4", code=0,
            setup=lambda i, o: fifo_reader(o / "o.mp4", _FIFO),
            check=lambda i, o, out: still_there(o / "o.mp4", stat.S_ISFIFO)
            and video_frames(_FIFO[-1]) == list(range(CLIP_FRAMES))),
    out_row("--out is a FIFO named .avi", lambda i, o: o / "o.avi",
            problem="cannot be streamed",
            setup=lambda i, o: contextlib.nullcontext(os.mkfifo(o / "o.avi"))),
    out_row("--out a full device (/dev/full)", lambda i, o: device(o, "full", "o.mp4"),
            problem="No space left"),
    out_row("--out a null device (/dev/null)", lambda i, o: device(o, "null", "o.mp4"),
            code=0, check=lambda i, o, out: still_there(o / "o.mp4", stat.S_ISCHR)),
    Row("run", "--out - with --detections -",
        lambda i, o: run(i.video.clip, "--out", "-", "--detections", "-"),
        names=lambda i, o: "-", problem="same file"),
]


def device(folder, name, filename):
    """A private ``/dev/<name>`` called ``filename`` in ``folder`` (root only, else skipped)."""
    path = folder / filename
    if not path.exists():   # a row calls its target twice: for the command and the message
        path = private_device(folder, name, filename)
    if path is None:
        pytest.skip("needs root to make a device node")
    return path
