"""Video output on PyAV: H.264 that plays in a browser, written atomically.

:class:`VideoSink` encodes frames (BGR arrays or decoded ``av.VideoFrame``
objects) to a temporary file beside the destination and renames it into
place when complete (:class:`~fastdet.files.atomic.StagedFile`).  The default
is what every browser and most tools play: H.264 (libx264), yuv420p, in an
MP4 whose index (the moov atom) comes before the media data (``+faststart``),
so the file streams.  A ``.webm`` is VP9 (libvpx-vp9) by default, WebM's own
codec; a codec the container cannot hold is refused at opening.

Odd sizes: yuv420p stores colour at half resolution, so H.264, HEVC, AV1,
VP9 and MPEG-4 need an even width and height.  A frame with an odd width or
height is padded by one column on the right and/or one row at the bottom,
copies of the last column or row; the picture is never rescaled (an
853x480 input gives an 854x480 output whose first 853 columns are the input).

Outputs that are not regular files (``-`` for standard output, a FIFO, a
device) are written through in place; MP4 and QuickTime there are
*fragmented* (the index ahead of each group of frames instead of one index
first), which plays while it streams; ``-``, and a FIFO or device whose
name has no suffix (``/dev/null``, ``/dev/stdout``), get fragmented MP4, and
AVI, which must seek back to finish, is refused.

Timestamps: frames are written with the ``pts`` they are given (in the
sink's ``time_base``, e.g. the input stream's), so variable and non-integer
frame rates (29.97 = 30000/1001) are kept; without one a frame is placed
one frame period after the previous.  A first timestamp above 0 is kept
(in MP4 as an edit list: players start at that time, as with the input);
when the first is negative, every frame is moved later by as much (MP4 would
cut the frames before 0).  Timestamps always increase: one that does not is
moved just after the previous frame.
"""

from __future__ import annotations

import contextlib
import numbers
import os
from fractions import Fraction
from pathlib import Path

import av
import cv2
import numpy as np
from av.video.reformatter import VideoReformatter

from ..errors import InputError
from ..files.atomic import STDOUT, StagedFile
from .codecs import (CRF_RANGE, DEFAULT_CODEC, DEFAULT_CRF, DEFAULT_PRESET, ENCODERS, MIN_SIDE,
                     NAMED_PRESETS)
from .frame_arrays import plane_view
from .standard_output import PipeWatch, ReaderGone, writes_standard_output

#: Containers by suffix; MP4 and QuickTime files get their index first.
CONTAINERS = {".mp4": "mp4", ".m4v": "mp4", ".mov": "mov", ".mkv": "matroska",
              ".webm": "webm", ".avi": "avi", ".ts": "mpegts"}
FASTSTART = frozenset({"mp4", "mov"})
#: Written in place (``-``, a FIFO, a device), MP4 and QuickTime are fragmented: an index
#: first needs the whole file, which a stream cannot be rewound to.
FRAGMENTED = "frag_keyframe+empty_moov+default_base_moof"
#: The container of ``-`` and of a FIFO or device whose name has no suffix.
STREAMED_CONTAINER = "mp4"
#: Containers that must seek back to finish (their index at the end): files only.
NEEDS_SEEKING = frozenset({"avi"})
#: The codecs each container holds, the natural one first: a container's first is the
#: codec of a video written there without one chosen (WebM holds only VP9 and AV1,
#: so a .webm is VP9; everything else is H.264).  FFmpeg's muxers refuse the others,
#: or (AV1 and VP9 in MPEG-TS) write them as a data stream no player shows.
HOLDS = {"mp4": ("h264", "hevc", "av1", "vp9", "mp4v"), "mov": ("h264", "hevc", "mp4v"),
         "matroska": ("h264", "hevc", "av1", "vp9", "mp4v"), "webm": ("vp9", "av1"),
         "avi": ("h264", "mp4v", "av1", "vp9"), "mpegts": ("h264", "hevc", "mp4v")}
#: What the containers are called in messages.
CONTAINER_NAMES = {"mp4": "MP4", "mov": "QuickTime (.mov)", "matroska": "Matroska (.mkv)",
                   "webm": "WebM", "avi": "AVI", "mpegts": "MPEG-TS (.ts)"}

# FFmpeg's colour tags (AVColorSpace etc.): what the BGR -> YUV conversion used.
_BT709, _UNSPECIFIED, _SMPTE170M, _LIMITED_RANGE = 1, 2, 6, 1


def even(n):
    """``n`` rounded up to an even number."""
    return n + (n & 1)


def codec_options(codec, crf=None, preset=None, threads=1):
    """FFmpeg encoder options for ``--codec/--crf/--preset``.

    Raises
    ------
    InputError
        For an unknown codec, one the installed FFmpeg lacks, a crf outside
        the encoder's range, an unknown x264/x265 preset, or a preset given
        to mp4v (which has none).
    """
    if codec not in ENCODERS:
        raise InputError(f"unknown codec {codec!r} (choose from {', '.join(available_codecs())})")
    if ENCODERS[codec] not in av.codecs_available:
        raise InputError(f"this FFmpeg cannot encode {codec} ({ENCODERS[codec]} is missing)")
    crf = DEFAULT_CRF[codec] if crf is None else crf
    low, high = CRF_RANGE[codec]
    if isinstance(crf, bool) or not isinstance(crf, numbers.Real):
        raise InputError(f"{codec} quality (--crf) must be a number {low}-{high}, got {crf!r}")
    if not low <= crf <= high:
        # x264 would clamp silently; say so instead.
        raise InputError(f"{codec} quality (--crf) must be {low}-{high}, got {crf}")
    if codec == "mp4v":
        if preset is not None:
            raise InputError("--preset does not apply to mp4v")
        return {"qmin": str(crf), "qmax": str(crf)}
    preset = DEFAULT_PRESET[codec] if preset is None else str(preset)
    if codec in NAMED_PRESETS and preset not in NAMED_PRESETS[codec]:
        raise InputError(f"{codec} has no preset {preset!r} (choose from "
                         f"{', '.join(NAMED_PRESETS[codec])})")
    if codec == "vp9":
        return {"crf": str(crf), "b": "0", "deadline": "realtime", "cpu-used": preset,
                "row-mt": "1"}
    options = {"crf": str(crf), "preset": preset}
    if codec == "hevc":
        options["x265-params"] = f"log-level=error:pools={threads}:frame-threads={threads}"
    return options


def _frame_rate(fps):
    """``fps`` as the exact fraction the stream is given (1/1001 steps at most),
    or an :class:`InputError` naming it."""
    try:
        if isinstance(fps, bool):
            raise TypeError
        rate = Fraction(fps).limit_denominator(1001000)
    except (TypeError, ValueError, OverflowError):
        rate = None
    if rate is None or rate <= 0:
        raise InputError(f"a video's frame rate must be a positive number, got {fps!r}")
    return rate


def _frame_size(size):
    """``size`` as ``(width, height)`` of whole positive pixels, or an :class:`InputError`."""
    try:
        width, height = size
        whole = int(width) == width and int(height) == height
    except (TypeError, ValueError, OverflowError):
        whole = False
    if not whole or width < 1 or height < 1:
        raise InputError(f"a video's size must be (width, height) in whole pixels, got {size!r}")
    return int(width), int(height)


def _time_base(time_base, rate):
    """``time_base`` as a positive Fraction (``1 / rate`` for ``None``), or an
    :class:`InputError`: 0 made every frame's timestamp a division by zero."""
    if time_base is None:
        return 1 / rate
    try:
        if isinstance(time_base, bool):
            raise TypeError
        value = Fraction(time_base)
    except (TypeError, ValueError, OverflowError):
        value = None
    if value is None or value <= 0:
        raise InputError(f"a video's time base must be a positive number of seconds, "
                         f"got {time_base!r}")
    return value


def check_encoder(codec, crf=None, preset=None):
    """Open ``codec`` with these options on a tiny picture, to refuse bad ones before any work.

    A batch calls this once on the client, so that a preset the encoder does
    not know fails the command with one line instead of every video on
    every worker.

    Raises
    ------
    InputError
        When :func:`codec_options` refuses the options or the encoder does.
    """
    options = codec_options(codec, crf, preset)
    if codec == "av1":
        os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1 prints its banner to stderr
    context = av.CodecContext.create(ENCODERS[codec], "w")
    context.width = context.height = 64
    context.pix_fmt = "yuv420p"
    context.time_base = Fraction(1, 25)
    context.options = options
    try:
        context.open()
    except av.error.FFmpegError:
        raise InputError(_refusal(codec, crf, preset)) from None


def refuse_encoder_options_without_video(codec=None, crf=None, preset=None, remedy="give --out"):
    """Raise :class:`InputError` when an encoder option is given but no video is written.

    Such an option would decide nothing, and options are never silently
    ignored (as mp4v refuses a preset).  ``None`` means not given;
    ``remedy`` ends the message (``fastdet batch``: drop ``--no-video``).
    """
    given = [option for option, value in (("--codec", codec), ("--crf", crf),
                                          ("--preset", preset)) if value is not None]
    if given:
        verb = "applies" if len(given) == 1 else "apply"
        raise InputError(f"{' and '.join(given)} {verb} only to the annotated video, which "
                         f"this run does not write ({remedy})")


def _refusal(codec, crf, preset):
    crf = DEFAULT_CRF[codec] if crf is None else crf
    preset = DEFAULT_PRESET.get(codec) if preset is None else preset
    return f"the {codec} encoder refuses --preset {preset} --crf {crf}"


def available_codecs():
    """The ``--codec`` names this installation's FFmpeg can encode."""
    return [name for name, encoder in ENCODERS.items() if encoder in av.codecs_available]


def pad_to_even(image):
    """An (H, W[, C]) array padded to even H and W with copies of its last row/column."""
    height, width = image.shape[:2]
    if height % 2 == 0 and width % 2 == 0:
        return image
    padded = np.empty((even(height), even(width)) + image.shape[2:], image.dtype)
    padded[:height, :width] = image
    padded[:height, width:] = image[:, width - 1:]
    padded[height:] = padded[height - 1:height]
    return padded


def _padded_yuv420p(frame):
    """A yuv420p frame with odd sides padded to even (see the module's rule)."""
    if frame.width % 2 == 0 and frame.height % 2 == 0:
        return frame
    padded = av.VideoFrame(even(frame.width), even(frame.height), "yuv420p")
    for index in range(3):
        source, target = plane_view(frame, index), plane_view(padded, index)
        # Chroma planes already have ceil(side / 2) rows and columns: only luma grows.
        target[:] = source if source.shape == target.shape else pad_to_even(source)
    padded.pts, padded.time_base = frame.pts, frame.time_base
    padded.colorspace, padded.color_range = frame.colorspace, frame.color_range
    return padded


class VideoSink(StagedFile):
    """A video file written atomically: H.264, yuv420p, index first by default.

    Parameters
    ----------
    path : str or Path
        Destination; its suffix chooses the container (``.mp4``, ``.m4v``,
        ``.mov``, ``.mkv``, ``.webm``, ``.avi``, ``.ts``).
    fps : float or Fraction
        Nominal frame rate (``Fraction(30000, 1001)`` for 29.97).
    size : tuple of int
        ``(width, height)`` of the frames to be written (odd sides are padded).
    codec : {'h264', 'hevc', 'av1', 'vp9', 'mp4v'}, optional
        Default: the container's own, H.264 but for VP9 in WebM (which holds
        only VP9 and AV1).  A codec the container cannot hold (:data:`HOLDS`)
        is refused here, saying which would do.
    crf : int, optional
        Quality (lower is better and bigger); for mp4v the fixed quantiser.
    preset : str, optional
        Encoder speed preset (x264/x265 names, SVT-AV1 and VP9 numbers).
    threads : int
        Encoder threads (>= 1).
    time_base : Fraction, optional
        Unit of the ``pts`` given to :meth:`write` (default ``1 / fps``).
    colour : tuple of int, optional
        The input's colour tags, ``(matrix, range)`` as
        :attr:`VideoSource.colour` gives them, kept in the
        output so that its decoded frames pass through unconverted.
        Default: BT.601 limited range, what BGR frames are converted with.

    Raises
    ------
    InputError
        When the destination cannot be written, its name has no suffix the
        container is chosen by, the container cannot hold the codec, the
        codec cannot be opened, or an argument has a value it cannot have.

    Examples
    --------
    >>> with VideoSink("out.mp4", 25, (1280, 720)) as sink:   # doctest: +SKIP
    ...     for frame in frames:                              # BGR uint8 arrays
    ...         sink.write(frame)
    """

    #: Whether the output is standard output and its reader closed it (``| head``).
    reader_gone = False

    def __init__(self, path, fps, size, codec=None, crf=None, preset=None, threads=1,
                 time_base=None, colour=None):
        # Checked before the temporary file exists.
        rate, size = _frame_rate(fps), _frame_size(size)
        time_base = _time_base(time_base, rate)
        if isinstance(threads, bool) or not isinstance(threads, numbers.Integral) or threads < 1:
            raise InputError(f"encoder threads must be a whole number >= 1, got {threads!r}")
        threads = int(threads)
        colour = _checked_colour(colour)
        container_format = _container_format(path)
        if codec is None:
            codec = _natural_codec(path, container_format)
        options = codec_options(codec, crf, preset, threads)
        if container_format is not None and codec not in HOLDS[container_format]:
            # FFmpeg refuses most of these at opening, without saying what would do;
            # AV1 and VP9 in MPEG-TS it wrote as a stream no player shows.
            raise InputError(f"cannot write {path}: {_cannot_hold(container_format, codec)}")
        least = MIN_SIDE.get(codec, 1)
        if min(even(size[0]), even(size[1])) < least:
            raise InputError(f"the {codec} encoder needs at least {least} pixels on each side, "
                             f"got {size[0]}x{size[1]} (choose another --codec)")
        super().__init__(path)
        if container_format is None:
            if self.in_place and not Path(path).suffix:
                container_format = STREAMED_CONTAINER    # /dev/null, a FIFO named ff
            else:
                self.discard()
                raise InputError(_unsupported_name(path))
        if self.in_place and container_format in NEEDS_SEEKING:
            self.discard()
            raise InputError(f"cannot write {path}: {container_format.upper()} cannot be "
                             "streamed to a file that is not a regular one (use .mp4, .mkv "
                             "or .ts)")
        self.codec = codec
        self._crf, self._preset = crf, preset
        self.size = size
        self.rate = rate
        self.time_base = time_base
        self.frames = 0
        self._last_pts = None
        self._pts_shift = 0
        self._reformatter = VideoReformatter()
        tags = _colour_tags(colour)
        #: Whether the output is tagged with (and BGR frames converted by) the BT.709 matrix.
        self.bt709 = tags[0] == _BT709
        try:
            self._open(container_format, options, threads, tags)
        except (av.error.FFmpegError, OSError, ValueError) as exc:
            self.discard()
            raise InputError(f"cannot write a {codec} video to {self.path}: "
                             f"{getattr(exc, 'strerror', None) or exc}") from None

    def _open(self, container_format, options, threads, tags):
        if self.codec == "av1":
            os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1 prints its banner to stderr
        container_options = {}
        if container_format in FASTSTART:
            container_options["movflags"] = FRAGMENTED if self.in_place else "+faststart"
        self._handle = self._pipe = None
        target = str(self.temporary)
        if self.in_place:
            # Through a Python file object: ``-`` continues this process's own stdout.
            target = self._handle = self.open("wb")
            if writes_standard_output(self.path):
                target = self._pipe = PipeWatch(self._handle)
        self._container = av.open(target, "w", format=container_format,
                                  container_options=container_options)
        stream = self._container.add_stream(ENCODERS[self.codec], rate=self.rate,
                                            options=options)
        stream.width, stream.height = even(self.size[0]), even(self.size[1])
        stream.pix_fmt = "yuv420p"
        if self.codec == "hevc" and container_format in FASTSTART:
            stream.codec_tag = "hvc1"  # the tag Apple's players require
        context = stream.codec_context
        context.time_base = self.time_base
        context.thread_count = threads
        (context.colorspace, context.color_range, context.color_primaries,
         context.color_trc) = tags
        try:
            context.open()  # fail now, before any frame, on a bad size or option
        except av.error.FFmpegError:
            raise ValueError(f"{_refusal(self.codec, self._crf, self._preset)} at "
                             f"{self.size[0]}x{self.size[1]}") from None
        if context.options:
            # FFmpeg leaves the options it did not understand here, silently otherwise.
            raise ValueError(f"the encoder ignores {', '.join(sorted(context.options))}")
        try:
            # The header now, not with the first packet: a container that cannot
            # hold the codec (AV1 or VP9 in .mov, before HOLDS) said so, as
            # "Invalid argument", only once the whole run had been done.
            self._container.start_encoding()
        except av.error.ArgumentError:
            raise ValueError(_cannot_hold(container_format, self.codec)) from None
        self._stream = stream

    # -- writing --------------------------------------------------------------------
    def write(self, frame, pts=None):
        """Encode one frame.

        Parameters
        ----------
        frame : ndarray or av.VideoFrame
            A BGR uint8 ``(height, width, 3)`` array, or a decoded frame of the
            sink's size (yuv420p frames are encoded as they are).
        pts : int, optional
            Presentation time in :attr:`time_base` units; default: one frame
            period after the previous frame.

        Raises
        ------
        InputError
            For a frame of another size or type, a ``pts`` that is not a whole
            number, a closed sink, or a failed write.
        """
        if self.closed:
            raise InputError(f"the video {self.path} is closed")
        if pts is not None and (isinstance(pts, bool) or not isinstance(pts, numbers.Integral)):
            # int() truncated 1.7 and raised a bare ValueError for NaN.
            raise InputError(f"a frame's pts is a whole number of time-base units, got {pts!r}")
        if isinstance(frame, np.ndarray):
            video_frame = self._from_bgr(frame)
        elif not isinstance(frame, av.VideoFrame):
            raise InputError(f"a frame is a numpy array or an av.VideoFrame, got "
                             f"{type(frame).__name__}")
        else:
            if (frame.width, frame.height) != self.size:
                raise InputError(f"frame of {frame.width}x{frame.height} does not fit a "
                                 f"{self.size[0]}x{self.size[1]} video")
            video_frame = frame
            if frame.format.name != "yuv420p":
                video_frame = self._reformatter.reformat(frame, format="yuv420p", threads=1)
            video_frame = _padded_yuv420p(video_frame)
        video_frame.pts = self._next_pts(pts)
        video_frame.time_base = self.time_base
        # A decoded frame's picture type would force the encoder's choice.
        video_frame.pict_type = av.video.frame.PictureType.NONE
        try:
            self._container.mux(self._stream.encode(video_frame))
        except (av.error.FFmpegError, OSError) as exc:
            self._refuse_closed_pipe()
            raise InputError(f"cannot write a video to {self.path}: "
                             f"{getattr(exc, 'strerror', None) or exc}") from None
        self._refuse_closed_pipe()
        self.frames += 1

    def _refuse_closed_pipe(self):
        if self._pipe is not None and self._pipe.broken:
            self.reader_gone = True
            raise ReaderGone(self.path)

    def _from_bgr(self, frame):
        if frame.dtype != np.uint8:
            raise InputError(f"a frame is BGR uint8, got {frame.dtype}")
        if frame.shape != (self.size[1], self.size[0], 3):
            raise InputError(f"frame of shape {frame.shape} does not fit a "
                             f"{self.size[0]}x{self.size[1]} video")
        frame = pad_to_even(frame)
        if not self.bt709:
            # OpenCV's conversion is BT.601 limited range, several times faster than swscale's.
            yuv = cv2.cvtColor(frame, cv2.COLOR_BGR2YUV_I420)
            return av.VideoFrame.from_numpy_buffer(yuv, format="yuv420p")
        bgr = av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="bgr24")
        return self._reformatter.reformat(bgr, format="yuv420p", dst_colorspace="ITU709",
                                          dst_color_range="MPEG", threads=1)

    def _next_pts(self, pts):
        if pts is None:
            step = max(1, round(1 / (self.rate * self.time_base)))
            pts = 0 if self._last_pts is None else self._last_pts + step
        else:
            pts = int(pts)
            if self._last_pts is None and pts < 0:
                # MP4's edit list would cut the frames before 0 from the video.
                self._pts_shift = -pts
            pts += self._pts_shift
        if self._last_pts is not None and pts <= self._last_pts:
            pts = self._last_pts + 1
        self._last_pts = pts
        return pts

    # -- finishing ------------------------------------------------------------------
    def close(self):
        """Finish the video and move it into place (a video without frames is discarded)."""
        if self.frames == 0:
            self.discard()
        else:
            super().close()

    def _finish(self):
        if self.reader_gone:
            with contextlib.suppress(av.error.FFmpegError, OSError):
                self._abandon()
            return
        try:
            self._container.mux(self._stream.encode(None))
            self._container.close()  # writes the index, moved to the front (faststart)
            if self._handle is not None:
                self._handle.close()
        except (av.error.FFmpegError, OSError) as exc:
            if self._pipe is not None and self._pipe.broken:
                self.reader_gone = True
                with contextlib.suppress(OSError):
                    self._handle.close()
                raise ReaderGone(self.path) from None
            raise InputError(f"cannot finish the video {self.path}: "
                             f"{getattr(exc, 'strerror', None) or exc}") from None

    def _abandon(self):
        try:
            container = getattr(self, "_container", None)
            if container is not None:
                container.close()
        finally:
            handle = getattr(self, "_handle", None)
            if handle is not None:
                handle.close()


def _container_format(path):
    """The container for ``path``: its suffix's; ``-`` gets MP4.

    ``None`` for a name without a suffix (a FIFO or device without one,
    ``/dev/null`` or a FIFO named ``ff``, is then given MP4 as ``-`` is:
    a stream has no name to choose by) or with a suffix fastdet cannot write.
    """
    if str(path) == STDOUT:
        return STREAMED_CONTAINER
    return CONTAINERS.get(Path(path).suffix.lower())


def _natural_codec(path, container_format):
    """The codec of a video written to ``path`` when none is chosen: the container's own.

    H.264 everywhere but WebM, which holds only VP9 and AV1: VP9 there, the
    format's usual codec, or an :class:`InputError` suggesting ``--codec``
    when this FFmpeg cannot encode it.
    """
    if container_format != "webm":
        return DEFAULT_CODEC
    natural = HOLDS["webm"][0]
    if ENCODERS[natural] not in av.codecs_available:
        others = [codec for codec in HOLDS["webm"] if ENCODERS[codec] in av.codecs_available]
        instead = f"give --codec {_either(others)}, or write" if others else "write"
        raise InputError(f"cannot write {path}: a WebM video is {natural} unless --codec says "
                         f"otherwise, and this FFmpeg cannot encode {natural} "
                         f"({ENCODERS[natural]} is missing): {instead} .mp4 or .mkv")
    return natural


def _cannot_hold(container_format, codec):
    """Why ``codec`` cannot go into ``container_format``, and what would do instead."""
    usable = [other for other in HOLDS[container_format]
              if ENCODERS[other] in av.codecs_available]
    instead = f"--codec {_either(usable)}, or write " if usable else "write "
    return (f"the {CONTAINER_NAMES[container_format]} format cannot hold {codec} (use "
            f"{instead}.mp4 or .mkv)")


def _either(names):
    """``a``, ``a or b``, ``a, b or c``."""
    return names[0] if len(names) == 1 else f"{', '.join(names[:-1])} or {names[-1]}"


def _unsupported_name(path):
    """The message for a name no container is chosen by."""
    name = Path(path).name
    if not Path(path).suffix and name.lower() in CONTAINERS:
        # ".mp4": a hidden file's name, all stem and no suffix (an empty $NAME.mp4).
        return (f"cannot write a video to {path}: {name} is a hidden file's name with no "
                f"suffix (its dot starts the name); name the video, e.g. video{name}")
    problem = "unsupported suffix" if Path(path).suffix else "the name has no suffix"
    return f"cannot write a video to {path} ({problem}; use one of {', '.join(CONTAINERS)})"


def _checked_colour(colour):
    """``colour`` as ``(matrix, range)`` ints (``None`` kept), or an :class:`InputError`.

    ``colour=5`` raised a bare TypeError; ``"x"`` and ``(1,)`` were taken.
    """
    if colour is None:
        return None
    try:
        matrix, colour_range = colour
    except (TypeError, ValueError):
        matrix = colour_range = None
    if not all(isinstance(v, numbers.Integral) and not isinstance(v, bool) and v >= 0
               for v in (matrix, colour_range)):
        raise InputError(f"colour is the (matrix, range) pair of FFmpeg's colour tags, as "
                         f"VideoSource.colour gives it, got {colour!r}")
    return int(matrix), int(colour_range)


def _colour_tags(colour):
    """``(matrix, range, primaries, transfer)`` to tag the output with."""
    matrix = None if colour is None else colour[0]
    if matrix == _BT709:
        return (_BT709, _LIMITED_RANGE, _BT709, _BT709)
    if matrix == _UNSPECIFIED:
        # Untagged input stays untagged: players then guess as they did for the input.
        return (_UNSPECIFIED, _LIMITED_RANGE, _UNSPECIFIED, _UNSPECIFIED)
    # BT.601 (SMPTE 170M) for converted BGR frames and for other inputs.
    return (_SMPTE170M, _LIMITED_RANGE, _SMPTE170M, _SMPTE170M)
