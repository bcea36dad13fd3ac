"""The encoders ``--codec`` names and their defaults: plain data, without importing PyAV.

Kept apart from :mod:`fastdet.video.sink` so that building the command line's
parser (every verb's options) does not load FFmpeg for a ``fastdet detect``.
"""

#: ``--codec`` names and the FFmpeg encoder behind each.
ENCODERS = {"h264": "libx264", "hevc": "libx265", "av1": "libsvtav1", "vp9": "libvpx-vp9",
            "mp4v": "mpeg4"}
#: Default quality (crf; for mp4v the fixed quantiser 2-31) and speed preset per codec,
#: chosen to keep up with detection on a 1280x720 stream (see README, "Video").
DEFAULT_CRF = {"h264": 23, "hevc": 28, "av1": 35, "vp9": 35, "mp4v": 5}
DEFAULT_PRESET = {"h264": "ultrafast", "hevc": "ultrafast", "av1": "12", "vp9": "8"}
