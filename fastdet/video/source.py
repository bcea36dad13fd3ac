"""Video input on PyAV (FFmpeg): files, network streams and cameras.

:class:`VideoSource` decodes the first video stream of a file, an
``http(s)://``, ``rtsp://``, ``udp://`` or ``tcp://`` URL, or a camera
(``/dev/videoN`` or its index ``N``) one frame at a time, so memory does not
grow with the video's length.  It reads the first frame at opening: every
problem with the input (missing, not a video, no frames, nothing received
within the timeout, ``start`` past the end) is reported as one
:class:`~fastdet.errors.InputError` line before any output exists.

Decoding uses FFmpeg's own threads; the frames come out as BGR uint8
arrays (OpenCV's convention, the same pixels ``cv2.VideoCapture`` gives) or,
for the pipelined run, as decoded ``av.VideoFrame`` objects that
:class:`~fastdet.video.frame_arrays.FrameConverter` turns into BGR, whole or only the rows the detector
searches.
"""

from __future__ import annotations

import contextlib
import math
import numbers
import os
import threading
from fractions import Fraction
from pathlib import Path
from urllib.parse import urlparse

import av

from ..errors import InputError
from .damage import InputDamage
from .frame_arrays import FrameConverter, upright
from .seek import REORDER_SLACK, seek_point
from .skipping import FrameSkipper, LeftOut

#: Frame rate assumed when a video states none.
FALLBACK_FPS = 25.0
#: Suffixes FFmpeg would open as a one-frame "video"; they are images.
IMAGE_SUFFIXES = frozenset({".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".gif",
                            ".ppm", ".pgm"})
#: URL schemes of sources that have no end and no length.
LIVE_SCHEMES = frozenset({"udp", "rtp", "rtsp", "rtsps", "rtmp", "srt", "tcp"})
#: URL schemes handed to FFmpeg's network protocols.
NETWORK_SCHEMES = LIVE_SCHEMES | {"http", "https"}
#: Seconds to wait for a network source or camera to connect, and for each read.
DEFAULT_TIMEOUT = 10.0
#: Most threads any part of a run is given: decoder threads here, a run's ``--threads``
#: (:func:`fastdet.video.stages.run_cores`, a batch's too) and frames scored at once
#: (:mod:`fastdet.video.ahead`).  Beyond what any decoder, x264 (128 at most) or
#: frame-level detection can use.
MAX_THREADS = 256


def whole_frame_number(value, option):
    """``value`` as an int, or an :class:`InputError` naming ``option`` when it is not a
    whole number (``int(1.5)`` started a range at frame 1)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise InputError(f"{option} must be a whole number of frames, got {value!r}")
    return int(value)


def checked_source(source):
    """``source`` as a path, URL or camera index, or a one-line error.

    Raises
    ------
    TypeError
        For anything that cannot name a video: ``None``, a float, a bool
        (``True`` opened camera 1), bytes.
    InputError
        For an empty name (it read as the current folder, ".") or a negative
        camera index (``/dev/video-1``).
    """
    if isinstance(source, numbers.Integral) and not isinstance(source, bool):
        if source < 0:
            raise InputError(f"a camera index is a whole number >= 0, got {source}")
        return int(source)
    if isinstance(source, os.PathLike):
        text = os.fspath(source)
    else:
        text = source
    if not isinstance(text, str):
        bytes_hint = " (decode a bytes path with os.fsdecode)" if isinstance(text, bytes) else ""
        raise TypeError(f"a video source is a path, a URL or a camera index, not "
                        f"{type(source).__name__}{bytes_hint}")
    if not text.strip():
        raise InputError(f"the video source is an empty name ({text!r}): give a file, a URL "
                         "or a camera")
    return source


def _source_kind(source):
    """``(what av.open gets, its format or None, kind)``; kind: file, network or camera."""
    # ASCII digits only: "٣".isdigit() too, and int() reads it as 3.
    if isinstance(source, int) or (isinstance(source, str) and source.isascii()
                                   and source.isdigit()):
        return f"/dev/video{int(source)}", "v4l2", "camera"
    text = os.fspath(source)
    if text.startswith("/dev/video"):
        return text, "v4l2", "camera"
    scheme = urlparse(text).scheme.lower()
    if scheme in NETWORK_SCHEMES:
        return text, None, "network"
    return text, None, "file"


def source_file(source):
    """The file a video source reads (a path), or ``None`` for a camera or a network URL."""
    if isinstance(source, VideoSource):
        return source.path
    url, _, kind = _source_kind(checked_source(source))
    return Path(url) if kind == "file" else None


def _interruptible(work, abandon):
    """Run ``work()`` so that a signal handler that raises cuts the wait short.

    The main thread runs Python's signal handlers only between bytecodes, and
    FFmpeg blocks in C while it connects or waits for a first packet (up to
    the timeout).  So, on the main thread, ``work`` runs on a daemon thread
    while the main thread waits on a lock, which a signal interrupts.  If the
    wait is cut short, the exception propagates at once and ``abandon()``
    runs on that thread once ``work`` returns, to close what it opened.
    Elsewhere (a worker thread of a batch run) ``work`` runs directly.
    """
    if threading.current_thread() is not threading.main_thread():
        work()
        return
    outcome = {}
    lock = threading.Lock()
    finished = threading.Event()

    def run():
        try:
            work()
        except BaseException as exc:   # handed to the waiting thread
            outcome["error"] = exc
        with lock:
            finished.set()
            abandoned = outcome.get("abandoned", False)
        if abandoned and "error" not in outcome:
            with contextlib.suppress(Exception):
                abandon()

    thread = threading.Thread(target=run, name="fastdet-open", daemon=True)
    thread.start()
    try:
        finished.wait()
    except BaseException:
        with lock:
            outcome["abandoned"] = not finished.is_set()
        if not outcome["abandoned"]:
            abandon()
        raise
    if "error" in outcome:
        raise outcome["error"]


def _protocol_options(url, timeout):
    """FFmpeg options that bound each read of a network protocol by ``timeout`` seconds."""
    scheme = urlparse(url).scheme.lower()
    if timeout is None:
        return {"rtsp_transport": "tcp"} if scheme.startswith("rtsp") else {}
    micros = str(int(timeout * 1e6))
    if scheme.startswith("rtsp"):
        # TCP interleaving: no lost packets; "timeout" is the socket's I/O timeout.
        return {"rtsp_transport": "tcp", "timeout": micros}
    if scheme == "udp":
        # The UDP protocol's own timeout ends in a bare EIO; PyAV's read timeout
        # (an interrupt callback) bounds it instead.  A full kernel buffer drops
        # packets rather than failing the stream.
        return {"overrun_nonfatal": "1", "fifo_size": "50000"}
    return {"rw_timeout": micros}


def _reason(exc):
    """FFmpeg's error as a short phrase (no errno, no repeated URL)."""
    if isinstance(exc, (av.error.ExitError, TimeoutError)):
        return "no data within the timeout (is the source there?)"
    text = getattr(exc, "strerror", None) or str(exc) or type(exc).__name__
    return " ".join(str(text).split())


def frame_rate(stream):
    """The stream's frame rate as a Fraction (its average rate; ``None`` if it states none)."""
    for rate in (stream.average_rate, stream.guessed_rate, stream.base_rate):
        if rate and 0 < rate < 1000:
            return Fraction(rate)
    return None


class VideoSource:
    """Frames of a video file, network stream or camera, decoded one at a time.

    Parameters
    ----------
    source : str, Path or int
        A file, an ``http(s)://``, ``rtsp://``, ``udp://`` or ``tcp://`` URL,
        a camera device ``/dev/videoN`` or a camera index ``N``.
    start : int
        Index of the first frame to yield (frames count from 0).  A file is
        decoded from the keyframe before it, found from its packets and
        checked frame by frame (:mod:`.seek`); anything else, and any file
        where a check fails, from the beginning: indices are exact either way.
    end : int, optional
        Index one past the last frame to yield; the stream's end by default.
    threads : int, optional
        Decoder threads (FFmpeg's frame and slice threads), 1-256; default:
        FFmpeg's choice.
    timeout : float or None
        Seconds to wait for a network source or camera to connect, and for
        each read after that (``None``: forever).
    strict : bool
        Damaged input is an :class:`InputError`: a packet the decoder cannot
        decode, a frame decoded with errors, a file that ends before its
        index says.  Otherwise (``strict=False``) decoding goes on wherever
        it can and :attr:`damage` records what happened.

    Attributes
    ----------
    name : str
        The source as given, for messages.
    fps : float
        Frames per second stated by the stream (``FALLBACK_FPS`` if none).
    rate : Fraction
        The same as an exact fraction (``30000/1001`` for 29.97 fps).
    time_base : Fraction
        Unit of the frames' ``pts``.
    size : tuple of int
        ``(width, height)`` as the video is shown: a video with a rotation
        tag (display matrix, as phones record) is turned upright, frames and
        size, as ``cv2.VideoCapture`` turns it.
    frame_count : int or None
        Frames in the whole stream as its header states them; ``None`` for a
        live source or when unknown.
    live : bool
        A stream without an end (UDP, RTSP, TCP, a camera, ...).
    colour : tuple of int
        FFmpeg's colour matrix and range tags of the frames (``(1, 1)``:
        BT.709, limited range), for a :class:`~fastdet.video.sink.VideoSink`
        that passes decoded frames through.
    damage : InputDamage
        Damage met so far (false when none); ``damage.describe(frames_read)``
        says it in one phrase.
    frames_read : int
        Frames yielded so far.

    Raises
    ------
    InputError
        With a one-line message when the source cannot be opened, holds no
        frames, sends nothing within ``timeout``, or ``start`` lies past its
        end; for an empty name, a negative camera index and an argument of
        the wrong value (``threads=0``).
    TypeError
        For a source that cannot name a video (``None``, a float, bytes, a
        bool).

    Notes
    -----
    A source is read once, like the stream it decodes: an iteration stopped
    early is continued by the next one, and iterating again after the last
    frame is an :class:`InputError` (open the video again instead).

    Examples
    --------
    >>> with VideoSource("clip.mp4") as video:              # doctest: +SKIP
    ...     print(video.fps, video.size, video.frame_count)
    ...     for frame in video:                             # BGR uint8 arrays
    ...         ...
    """

    def __init__(self, source, start=0, end=None, *, threads=None, timeout=DEFAULT_TIMEOUT,
                 strict=True):
        source = checked_source(source)
        self.name = str(source)
        self.damage = InputDamage(self.name, strict)
        self.frames_read = 0
        self._read_to_end = False
        #: Frames :meth:`decoded_frames` left undecoded (its ``needed`` ruled them out).
        self.frames_left_undecoded = 0
        self.start = whole_frame_number(start, "--start")
        self.end = None if end is None else whole_frame_number(end, "--end")
        if self.start < 0:
            raise InputError(f"--start must be >= 0, got {self.start}")
        if self.end is not None and self.end <= self.start:
            raise InputError(f"--end ({self.end}) must be greater than --start ({self.start})")
        if timeout is not None and not (isinstance(timeout, numbers.Real)
                                        and 0 < timeout < math.inf):
            raise InputError(f"--timeout must be a positive number of seconds, got {timeout!r}")
        if threads is not None and (isinstance(threads, bool)
                                    or not isinstance(threads, numbers.Integral)
                                    or not 1 <= threads <= MAX_THREADS):
            # int() took "x" as a bare ValueError, truncated 1.5 and passed -1 to FFmpeg.
            raise InputError(f"decoder threads must be a whole number 1-{MAX_THREADS} "
                             f"(None: FFmpeg's choice), got {threads!r}")
        url, fmt, self.kind = _source_kind(source)
        self.url = url
        self.path = Path(url) if self.kind == "file" else None
        if self.kind == "file":
            self._check_file()
        options = _protocol_options(url, timeout) if self.kind == "network" else {}
        self._open_arguments = (url, fmt, options, None if timeout is None else (timeout, timeout))
        self._threads = threads
        if self.kind == "file":
            self._open_and_read_first()
        else:
            # A connection or camera may take up to the timeout to answer.
            _interruptible(self._open_and_read_first, self._abandon)
        self.size = (self._first.width, self._first.height)
        self.colour = (int(self._first.colorspace), int(self._first.color_range))
        self._converter = FrameConverter()
        self._first_bgr = None
        self.damage.expected = self.expected_frames

    # -- opening --------------------------------------------------------------------
    def _open_and_read_first(self):
        self._open()
        try:
            self._first = self._read_first()
        except BaseException:
            self._container.close()
            raise

    def _abandon(self):
        """Close what an interrupted :meth:`_open_and_read_first` opened once it returns."""
        container = getattr(self, "_container", None)
        if container is not None:
            container.close()

    def _open(self):
        url, fmt, options, timeout = self._open_arguments
        try:
            self._container = av.open(url, format=fmt, options=options, timeout=timeout)
        except (av.error.FFmpegError, OSError) as exc:
            raise InputError(self._open_failure(exc)) from None
        try:
            self._open_stream(self._threads)
        except BaseException:
            self._container.close()
            raise
        self._restart_decoding()

    def _restart_decoding(self):
        """Decode from the container's position on, with a new :class:`FrameSkipper`."""
        self._skipper = FrameSkipper(self._stream.codec_context, enabled=self.kind == "file")
        self._decoded = self._frames_from_container(self._skipper)

    def _check_file(self):
        path = self.path
        if not path.exists():
            raise InputError(f"video not found: {path}")
        if not path.is_file() and not path.is_char_device() and not path.is_fifo():
            raise InputError(f"not a video file: {path}")
        if path.suffix.lower() in IMAGE_SUFFIXES:
            raise InputError(f"{path} is an image, not a video (use `fastdet detect`)")

    def _open_failure(self, exc):
        if self.kind == "file":
            return f"cannot read {self.name} as a video (not a video file or corrupt)"
        if self.kind == "camera" and isinstance(exc, FileNotFoundError):
            return f"no camera at {self.url}"
        return f"cannot open {self.name}: {_reason(exc)}"

    def _open_stream(self, threads):
        container = self._container
        if not container.streams.video:
            raise InputError(f"{self.name} holds no video stream")
        stream = self._stream = container.streams.video[0]
        stream.thread_type = "AUTO"
        if threads is not None:
            stream.thread_count = int(threads)
        self.rate = frame_rate(stream) or Fraction(FALLBACK_FPS)
        self.fps = float(self.rate)
        self.time_base = stream.time_base or 1 / self.rate
        scheme = urlparse(self.name).scheme.lower()
        self.live = (self.kind == "camera" or scheme in LIVE_SCHEMES
                     or container.duration is None)
        self.frame_count = None
        self._count_from_index = False
        if not self.live:
            if stream.frames:
                self.frame_count, self._count_from_index = int(stream.frames), True
            elif container.duration:
                # No index (MPEG-TS and some Matroska files): estimate from the duration.
                self.frame_count = int(round(container.duration / 1e6 * self.fps))
        self._index = 0
        #: Why a live stream ended (``None`` while it runs, and for files).
        self.ended = None

    def _frames_from_container(self, skipper):
        """Decoded frames in order; damage recorded (or raised when strict), read failures
        turned into :class:`InputError`.

        Packets are decoded one by one, so that one the decoder cannot read is
        skipped rather than ending the stream.
        """
        stream = self._stream
        packets = self._container.demux(stream)
        while True:
            try:
                packet = next(packets)
            except StopIteration:
                # The packets held back, then the flush (an empty packet).
                yield from self._decode_packets(skipper.finished(), skipper)
                yield from skipper.remaining()
                return
            except (av.error.FFmpegError, OSError) as exc:
                if self.live and self._index > 0 and isinstance(exc, (av.error.ExitError,
                                                                      TimeoutError)):
                    # A live stream has no end but silence.
                    self.ended = f"no data from {self.name} within the timeout: stream ended"
                    return
                if self._index == 0:
                    raise InputError(f"cannot read {self.name} as a video: "
                                     f"{_reason(exc)}") from None
                self.damage.ended_early(self._index - 1, _reason(exc))
                return
            yield from self._decode_packets(skipper.demuxed(packet), skipper)

    def _decode_packets(self, packets, skipper):
        """The frames of ``packets``, each after the placeholders
        (:class:`~fastdet.video.skipping.LeftOut`) of the frames left out before
        it (see :mod:`fastdet.video.skipping`)."""
        stream = self._stream
        for packet in packets:
            try:
                frames = stream.decode(packet)
            except av.error.FFmpegError as exc:
                skipper.stop()   # its frame is lost: the count is off from here
                self.damage.undecodable_packet(self._index - 1, _reason(exc))
                continue
            for frame in frames:
                yield from skipper.decoded(frame)
                if frame.is_corrupt and self._index >= self.start:
                    self.damage.corrupt_frame(self._index)
                yield upright(frame)   # as players show it (a phone's portrait video)

    def _read_first(self):
        # Reading a frame is the only reliable test of "has frames": headers
        # may be missing or wrong.
        if self.kind == "file" and self.start > REORDER_SLACK:
            frame = self._seek_to_start()
            if frame is not None:
                return frame
            self._container.close()   # decode from the beginning instead
            self._open()
        if self.kind == "file" and self.start > 0:
            # The frames before the first wanted: as few decoded as can be.
            self._skipper.start(lambda index: index >= self.start, lambda: self._index)
        for frame in self._decoded:
            if self._index == self.start:
                return frame   # never left out: it is needed
            self._index += 1
        if self.start == 0:
            raise InputError(f"{self.name} holds no frames")
        total = "" if self.frame_count is None else f" ({self.frame_count} frames)"
        raise InputError(f"--start {self.start} is past the end of {self.name}{total}")

    def _seek_to_start(self):
        """Frame ``start`` decoded from the keyframe before it, or None if unsure (see seek)."""
        point = seek_point(self._container, self._stream, self.start)
        if point is None:
            return None
        try:
            self._container.seek(point.keyframe_pts, stream=self._stream, backward=True,
                                 any_frame=False)
        except (av.error.FFmpegError, OSError):
            return None
        self._restart_decoding()
        # The frames before the wanted one, as few decoded as can be; their
        # placeholders (LeftOut) carry the timestamps checked below.
        self._skipper.skip_before(point.expected_pts[self.start - point.keyframe_index])
        expected = iter(point.expected_pts)
        index = point.keyframe_index
        for frame in self._decoded:
            if frame.pts is not None and frame.pts < point.keyframe_pts:
                continue   # leading pictures of an open GOP: they belong before the keyframe
            if frame.pts != next(expected, None):
                return None
            if index == self.start:
                self._index = index
                return frame
            index += 1
        return None

    # -- frames ---------------------------------------------------------------------
    @property
    def closed(self):
        """Whether :meth:`close` was called (its frames can no longer be read)."""
        return getattr(self, "_container", None) is None

    @property
    def first_frame(self):
        """The first frame to yield as BGR, read at opening (``None`` once iteration began)."""
        if self._first is None:
            return None
        if self._first_bgr is None:
            self._first_bgr = self._converter.to_bgr(self._first)
        return self._first_bgr

    @property
    def expected_frames(self):
        """Frames this source should yield (``None`` if unknown, e.g. live)."""
        last = self.frame_count
        if self.end is not None:
            last = self.end if last is None else min(last, self.end)
        return None if last is None else max(last - self.start, 0)

    def decoded_frames(self, needed=None):
        """Yield the decoded ``av.VideoFrame`` objects in order (no conversion).

        A frame whose size differs from the first ends the stream with an
        :class:`InputError`; so does a read failure after the first frame.

        Parameters
        ----------
        needed : callable, optional
            ``needed(index) -> bool``: whether the caller looks at frame
            ``index``.  Frames it does not need and no other frame is
            predicted from may then stay undecoded, and ``None`` is yielded
            in their place (files only; see :mod:`fastdet.video.skipping`).
            Frames it needs are always decoded, the same pixels as without
            it.
        """
        if self._container is None:
            raise InputError(f"{self.name} is closed")
        if self._read_to_end:
            # A second pass would silently yield nothing: a stream is read once.
            raise InputError(f"{self.name}: all {self.frames_read} frames were read; "
                             "open it again to read them once more")
        first, self._first = self._first, None
        if first is not None:
            self._index += 1
            self.frames_read += 1
            yield first
        if needed is not None and self.kind == "file":
            self._skipper.start(needed, lambda: self._index)
        else:
            self._skipper.stop()   # nothing to leave out: no bookkeeping per frame
        for frame in self._decoded:
            if self.end is not None and self._index >= self.end:
                self._read_to_end = True
                return
            if isinstance(frame, LeftOut):
                if needed is None or needed(self._index):
                    # Only where the decoder lost frames of a damaged stream
                    # after the skipping had counted them: damage like those.
                    self.damage.undecodable_packet(self._index - 1, "a frame after lost ones "
                                                   "was left undecoded")
                    continue
                self._index += 1
                self.frames_read += 1
                self.frames_left_undecoded += 1
                yield None
                continue
            if (frame.width, frame.height) != self.size:
                raise InputError(f"{self.name}: the frame size changes from "
                                 f"{self.size[0]}x{self.size[1]} to {frame.width}x{frame.height} "
                                 f"at frame {self._index}")
            self._index += 1
            self.frames_read += 1
            yield frame
        if self._container is None:
            # Closed while its frames were read: not the file ending early.
            raise InputError(f"{self.name} is closed")
        self._read_to_end = True
        last = self.frame_count if self.end is None else min(self.end, self.frame_count or 0)
        if self._count_from_index and self._index < last and self.damage.ended_after is None:
            # The index promised more: the file is cut short or its data is damaged.
            self.damage.ended_early(self._index - 1)

    def __iter__(self):
        """Yield BGR uint8 frames of shape (height, width, 3), in order."""
        return self.frames()

    def frames(self, skip=None, needed=None):
        """Yield the frames in order as BGR arrays, optionally without converting some.

        Parameters
        ----------
        skip : callable, optional
            Called before each frame after the first; when it returns True the
            frame is decoded (the codec needs every frame) but not converted,
            and ``None`` is yielded in its place.
        needed : callable, optional
            ``needed(index) -> bool``: frames it rules out are not converted
            and, where no other frame needs them, not decoded either (as in
            :meth:`decoded_frames`); ``None`` is yielded in their place.  The
            first frame, read at opening, is always given.

        Yields
        ------
        ndarray of uint8, shape (height, width, 3), or None
        """
        first_bgr = self.first_frame
        for number, frame in enumerate(self.decoded_frames(needed)):
            if number == 0 and first_bgr is not None:
                yield first_bgr
            elif (frame is None or (skip is not None and skip())
                  or (needed is not None and not needed(self._index - 1))):
                yield None
            else:
                yield self._converter.to_bgr(frame)

    def close(self):
        """Release the decoder and the connection (idempotent)."""
        container = getattr(self, "_container", None)
        if container is not None:
            self._container = None
            self._first = None
            self._decoded.close()
            container.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __del__(self):
        with contextlib.suppress(Exception):
            self.close()
