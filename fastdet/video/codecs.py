"""The encoders ``--codec`` names and their defaults: plain data, without importing PyAV.

Kept apart from :mod:`fastdet.video.sink` so that building the command line's
parser (every verb's options) does not load FFmpeg for a ``fastdet detect``.
"""

#: ``--codec`` names and the FFmpeg encoder behind each.
ENCODERS = {"h264": "libx264", "hevc": "libx265", "av1": "libsvtav1", "vp9": "libvpx-vp9",
            "mp4v": "mpeg4"}
#: The codec of an annotated video when none is chosen: the one every browser plays.
DEFAULT_CODEC = "h264"
#: Default quality (crf; for mp4v the fixed quantiser 2-31) and speed preset per codec,
#: chosen to keep up with detection on a 1280x720 stream (see README, "Video").
DEFAULT_CRF = {"h264": 23, "hevc": 28, "av1": 35, "vp9": 35, "mp4v": 5}
DEFAULT_PRESET = {"h264": "ultrafast", "hevc": "ultrafast", "av1": "12", "vp9": "8"}
#: The encoders' own crf ranges (x264/x265 0-51; SVT-AV1 and libvpx 0-63; mp4v's quantiser 2-31).
CRF_RANGE = {"h264": (0, 51), "hevc": (0, 51), "av1": (0, 63), "vp9": (0, 63), "mp4v": (2, 31)}
#: x264's and x265's preset names (shared): checked here because x264 prints its own
#: complaint about an unknown one straight to stderr, past FFmpeg's logging.
NAMED_PRESETS = {codec: ("ultrafast", "superfast", "veryfast", "faster", "fast", "medium", "slow",
                         "slower", "veryslow", "placebo") for codec in ("h264", "hevc")}
#: Fewest pixels an encoder takes on each side of a picture.  SVT-AV1 (its
#: version in the PyAV wheel) refuses sides under 4 on stderr, and with a side
#: under 32 and the other over 64 (1280x16, 24x1280) it waits forever inside
#: the encoder, signals and all: such sizes are refused before it opens.
MIN_SIDE = {"av1": 32}
