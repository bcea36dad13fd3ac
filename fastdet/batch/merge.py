"""The segments of a long video joined into its outputs: detections with whole-video ids, one video.

Segments write their detections as JSON lines with their own track ids;
:func:`merge_detections` renumbers them (:class:`~fastdet.batch.boundary.IdMap`)
and writes the requested format, and :func:`read_part` gives the renumbered
boxes to the pass that draws them into the segment's annotated video.
:func:`concatenate_videos` joins the segments' annotated videos by copying
their compressed packets into one container (PyAV), without decoding or
re-encoding: every segment starts with a key frame because each was encoded
on its own.
"""

from __future__ import annotations

import json
from fractions import Fraction
from pathlib import Path

import av
import numpy as np

from ..detector.detections import Detections
from ..errors import InputError
from ..files.atomic import atomic_path
from ..video.detection_files import DetectionWriter
from ..video.sink import CONTAINERS, FASTSTART


def read_part(path, ids):
    """Yield ``(frame, Detections)`` of a segment's jsonl detections, in whole-video ids.

    Each frame's boxes are listed by id, as the whole-video run lists them.
    """
    with open(path, encoding="utf-8") as handle:
        for line in handle:
            record = json.loads(line)
            boxes = record["boxes"]
            tracks = [ids(box["track"]) for box in boxes]
            order = sorted(range(len(boxes)), key=tracks.__getitem__)
            yield record["frame"], Detections(
                np.array([boxes[k]["box"] for k in order], np.int32).reshape(-1, 4),
                [boxes[k]["score"] for k in order], [tracks[k] for k in order])


def merge_detections(parts, id_maps, target, fmt):
    """Write the detections of consecutive segments as one file in whole-video ids.

    Parameters
    ----------
    parts : list of Path
        The segments' jsonl detections files, in frame order.
    id_maps : list of IdMap
        One per part.
    target : Path
    fmt : {'jsonl', 'csv', 'mot'}
    """
    with DetectionWriter(target, fmt) as out:
        for part, ids in zip(parts, id_maps):
            for frame, detections in read_part(part, ids):
                out.write(frame, detections)


def concatenate_videos(parts, target):
    """Join video files of one stream layout into ``target``, packet by packet.

    Each part's timestamps are shifted to start where the previous part
    ended, so the result plays as one video.

    Raises
    ------
    InputError
        When a part cannot be read or the container cannot be written.
    """
    target = Path(target)
    try:
        container = _container_format(target)
        # Index first (+faststart), like every MP4 VideoSink writes: the page plays it inline.
        options = {"movflags": "+faststart"} if container in FASTSTART else {}
        with atomic_path(target) as tmp, av.open(str(tmp), "w", format=container,
                                                 container_options=options) as out:
            stream = None
            offset = Fraction(0)           # seconds
            for part in parts:
                with av.open(str(part)) as source:
                    video = source.streams.video[0]
                    base = video.time_base
                    if stream is None:
                        stream = out.add_stream_from_template(video)
                    shift = round(offset / base)
                    end = offset
                    for packet in source.demux(video):
                        if packet.dts is None:      # the demuxer's end-of-stream marker
                            continue
                        packet.dts += shift
                        if packet.pts is not None:
                            packet.pts += shift
                            end = max(end, (packet.pts + max(packet.duration or 0, 1)) * base)
                        packet.stream = stream
                        out.mux(packet)
                    offset = end
    except av.FFmpegError as exc:
        raise InputError(f"cannot join the segments of {target}: {exc}") from None


def _container_format(path):
    return CONTAINERS.get(Path(path).suffix.lower())
