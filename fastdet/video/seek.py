"""Exact seeking to a frame index: from the nearest keyframe, checked frame by frame.

Frame ``i`` of a video is the ``i``-th picture in presentation order, which
timestamps alone do not give for variable or irregular rates.  The packets
do: demuxing (no decoding, tens of thousands of packets a second) lists
every packet's timestamp and whether it is a keyframe; sorted, the
timestamps are the frames in presentation order.  Decoding starts at the
last keyframe at or before the wanted frame, and every frame decoded from
there is checked against that list; :class:`VideoSource` decodes from the
beginning instead whenever anything does not match.
"""

from __future__ import annotations

from dataclasses import dataclass

#: Packets demuxed beyond the wanted frame: more than any B-frame reordering delays a frame.
REORDER_SLACK = 64


@dataclass(frozen=True)
class SeekPoint:
    """Where to start decoding to reach a frame, and the timestamps to expect from there."""

    keyframe_pts: int
    keyframe_index: int
    expected_pts: tuple


def seek_point(container, stream, target):
    """The keyframe to decode from to reach frame ``target``, or None when it cannot tell.

    Demuxes from the container's current position (its start), so the
    caller must seek afterwards.

    Returns
    -------
    SeekPoint or None
        None when a packet has no timestamp, timestamps repeat, or the
        stream ends before ``target``.
    """
    packets = []
    demuxed = container.demux(stream)
    try:
        for packet in demuxed:
            if packet.size == 0:
                continue   # the demuxer's end-of-stream marker
            if packet.pts is None:
                return None
            packets.append((packet.pts, packet.is_keyframe))
            if len(packets) > target + REORDER_SLACK:
                break
    finally:
        demuxed.close()
    order = sorted(pts for pts, _ in packets)
    if target >= len(order) or len(set(order)) != len(order):
        return None
    target_pts = order[target]
    keyframes = [pts for pts, key in packets if key and pts <= target_pts]
    if not keyframes:
        return None
    keyframe_pts = max(keyframes)
    index = order.index(keyframe_pts)
    return SeekPoint(keyframe_pts, index, tuple(order[index:]))
