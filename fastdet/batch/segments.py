"""Cutting a long video into segments: their length, their warm-up, their boundaries.

``--segment 500`` splits a video of more than 500 frames into
``ceil(frames / 500)`` segments, ``--segment 30s`` into segments of 30 seconds.
Without patch tracking the segments are searched in parallel and replayed in
one pass (:mod:`fastdet.batch.split_search`): they need no warm-up and are of
equal length.  With patch tracking (or a warm-up asked for), every segment
but the first re-processes :func:`warmup_frames` frames before its start, so
the boundaries are placed to give the segments equal work: the first is
longer by a warm-up.

How long a warm-up must be, for the ``[track]`` settings:

* exponential heat smoothing (the default) forgets a frame's heat by a factor
  ``1 - heat_alpha`` per full search; after ``n`` searches the heat of the
  frames before the warm-up weighs ``(1 - alpha) ** n`` of what it did.  The
  warm-up lasts until that is ``2 ** -MEMORY_BITS``: 174 searches for the
  default ``alpha = 0.25``.  Heat reaches about ``2 ** 5`` and the smallest
  heat a hit adds is about ``2 ** -17``, so what remains lies ~50 binary
  orders below anything a frame adds, where float32 rounding has made both
  runs' maps bit for bit equal (measured: 150-160 searches suffice on the
  looped test clip).  :mod:`fastdet.batch.boundary` checks that it did;
* FIR smoothing holds exactly the last ``heat_frames`` maps;
* tracks are dropped after ``max_missed`` unconfirmed searches and a box is
  the mean of the last ``box_frames`` measurements;

and the warm-up starts on the search schedule (a multiple of ``every``, and of
``every * heat_frames`` for FIR, whose ring of maps must be in phase).  With
patch tracking the searches follow triggers, which a warm-up cannot replay
reliably: such boundaries usually fail the check and are redone from the
video's start, so segmenting does not pay with ``--track``.
"""

from __future__ import annotations

import math
import re

from ..errors import InputError

#: Binary orders by which the heat from before a warm-up must have decayed.
MEMORY_BITS = 72

_SPEC = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*(s|sec|seconds?)?\s*$")


def parse_segment(spec):
    """``"500"`` -> ``(500, None)`` frames, ``"30s"`` -> ``(None, 30.0)`` seconds.

    Raises
    ------
    InputError
        For anything else, or a length that is not positive.
    """
    match = _SPEC.match(str(spec))
    if not match:
        raise InputError(f"--segment takes frames (500) or seconds (30s), got {spec!r}")
    value, seconds = float(match.group(1)), match.group(2) is not None
    if value <= 0 or (not seconds and not value.is_integer()):
        raise InputError(f"--segment must be a positive number of frames or seconds, got {spec!r}")
    return (None, value) if seconds else (int(value), None)


def segment_frames(spec, fps):
    """Frames per segment for a parsed ``spec`` and the video's frame rate."""
    frames, seconds = spec
    return frames if frames is not None else max(1, round(seconds * fps))


def warmup_frames(track_config):
    """Frames a segment re-processes before its start (see the module notes).

    Parameters
    ----------
    track_config : TrackConfig

    Returns
    -------
    warmup : int
        Frames.
    align : int
        The warm-up starts on a multiple of this frame index.
    """
    cfg = track_config
    if cfg.heat_smoothing == "exponential":
        keep = 1.0 - cfg.heat_alpha
        heat = 1 if keep <= 0 else math.ceil(MEMORY_BITS * math.log(2) / -math.log(keep))
    elif cfg.heat_smoothing == "fir":
        heat = cfg.heat_frames
    else:
        heat = 0
    searches = max(heat, cfg.max_missed + cfg.box_frames + 1)
    period = cfg.every or 1
    align = period * (cfg.heat_frames if cfg.heat_smoothing == "fir" else 1)
    return searches * period, align


def plan_segments(frame_count, length, warmup, align=1):
    """The segments of a video: ``[(start, end, warm_start), ...]``.

    Parameters
    ----------
    frame_count : int or None
        Frames in the video (its header); ``None``: not split.
    length : int
        Frames per segment asked for.
    warmup : int
        :func:`warmup_frames`.
    align : int
        Warm-ups start on multiples of this.

    Returns
    -------
    list of tuple
        ``end`` of the last segment is ``None`` (to the video's real end,
        whatever the header says); ``warm_start`` is where the segment's
        reading begins (its ``start`` for the first).
    """
    if frame_count is None or frame_count <= length:
        return [(0, None, 0)]
    count = math.ceil(frame_count / length)
    # The first segment has no warm-up; each other one processes `warmup` frames more, at the
    # same cost (segments detect only: the annotated video is drawn afterwards).
    extra = min(warmup, frame_count)
    first = (frame_count + (count - 1) * extra) / count
    rest = (frame_count - first) / (count - 1)
    starts = sorted({0} | {round(first + k * rest) for k in range(count - 1)})
    starts = [s for s in starts if 0 <= s < frame_count]
    segments = []
    for k, start in enumerate(starts):
        end = starts[k + 1] if k + 1 < len(starts) else None
        warm_start = max(0, start - warmup) // align * align
        segments.append((start, end, warm_start))
    return segments
