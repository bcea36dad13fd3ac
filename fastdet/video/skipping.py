"""Leaving frames undecoded that nobody looks at and no other frame needs.

A run that searches every fifth frame and writes only detections looks at
one frame in five; the others only count.  Most H.264 and HEVC streams hold
pictures that no other picture is predicted from (the non-reference
B-frames: 40 % of the frames x264 writes by default), and FFmpeg can leave
those undecoded (``skip_frame = NONREF``) while decoding the rest exactly as
before.  On the 1000-frame bench input that is 318 of the 800 frames a
``--every 5`` run does not look at, and 36 % of the decoder's CPU time.

The catch is to know, when a packet goes to the decoder, which frame of the
video it is: frame ``i`` is the ``i``-th in presentation order, packets come
in decoding order, and a B-frame's packet follows pictures shown after it.
So packets are demuxed :data:`LOOKAHEAD` ahead of the decoder, more than any
H.264 or HEVC stream reorders (at most 16 pictures), and a packet's frame
index is the count of frames already out plus the packets still pending
with an earlier timestamp.  The decoder leaves out only the pictures it may
(a reference picture flagged by mistake is decoded anyway), and a
placeholder takes each left-out frame's place, in timestamp order, so every
later frame keeps its index.

Anything that breaks the count turns the skipping off for the rest of the
stream (every frame decoded, as without it): a packet without a timestamp,
two with the same one, or a frame the decoder dropped on its own.  On a
damaged stream a packet left out is never found undecodable, so its frame
keeps its place where decoding everything would have lost it.
"""

from __future__ import annotations

import bisect
import collections

#: Packets demuxed ahead of the decoder: more than H.264 and HEVC reorder (16).
LOOKAHEAD = 17


class LeftOut:
    """Stands in for a frame left undecoded, at its timestamp ``pts``."""

    __slots__ = ("pts",)

    def __init__(self, pts):
        self.pts = pts


class FrameSkipper:
    """Decides, packet by packet, which frames may stay undecoded.

    Parameters
    ----------
    codec_context : av.CodecContext
        The stream's decoder; its ``skip_frame`` is set before each packet.
    enabled : bool
        ``False`` for a source that is never skipped in (a live stream): no
        timestamps are kept, however long it runs.

    Notes
    -----
    Use: :meth:`demuxed` for each packet as it is read (which returns the
    packets to decode now), :meth:`decoded` for each frame the decoder gives
    (placeholders to yield before it), :meth:`finished` at the end.
    Skipping starts once :meth:`start` is given the frames that are needed,
    or :meth:`skip_before` a timestamp (the frames a seek decodes on its way
    to the first one wanted).
    """

    def __init__(self, codec_context, enabled=True):
        self._context = codec_context
        self._needed = None
        self._next_index = None
        self._before = None
        self._waiting = collections.deque()   # demuxed, not yet sent to the decoder
        self._pending = []                    # sorted pts of frames not out yet
        self._left_out = set()                # pts sent with skip_frame = NONREF
        self._broken = not enabled
        #: Placeholders given so far.
        self.left_out = 0

    @property
    def active(self):
        """Whether frames are being left out."""
        return (self._needed is not None or self._before is not None) and not self._broken

    def start(self, needed, next_index):
        """Leave out frames for which ``needed(index)`` is false, from now on.

        Parameters
        ----------
        needed : callable
            ``needed(index) -> bool`` for frame indices (presentation order).
        next_index : callable
            The index of the next frame :meth:`decoded` will see.
        """
        self._needed, self._next_index, self._before = needed, next_index, None

    def skip_before(self, pts):
        """Leave out frames shown before timestamp ``pts``, from now on."""
        self._needed, self._before = None, pts

    def stop(self):
        """Decode every frame from now on (placeholders still given for those left out);
        once those are given, no timestamps are kept."""
        self._broken = True
        self._context.skip_frame = "DEFAULT"

    def demuxed(self, packet):
        """Yield the packets to send to the decoder now, in order (``packet`` or older ones).

        Each is given its ``skip_frame`` setting as it is yielded: decode it
        before asking for the next.
        """
        if self._broken and not self._left_out:
            self._pending.clear()   # nothing left to place: no timestamps to keep
        elif packet.pts is None or packet.size == 0:
            if packet.size:
                self.stop()   # a frame without a timestamp: the count cannot be kept
        else:
            position = bisect.bisect_left(self._pending, packet.pts)
            if position < len(self._pending) and self._pending[position] == packet.pts:
                self.stop()   # two frames at one timestamp: their order is unknown
            self._pending.insert(position, packet.pts)
        self._waiting.append(packet)
        while len(self._waiting) > LOOKAHEAD or (self._waiting and not self.active):
            yield self._prepare(self._waiting.popleft())

    def finished(self):
        """Yield the packets still held back (to send before flushing the decoder)."""
        while self._waiting:
            yield self._prepare(self._waiting.popleft())

    def _prepare(self, packet):
        skip = False
        if self.active and packet.pts is not None and packet.size:
            if self._needed is not None:
                index = self._next_index() + bisect.bisect_left(self._pending, packet.pts)
                skip = not self._needed(index)
            else:
                skip = packet.pts < self._before
        self._context.skip_frame = "NONREF" if skip else "DEFAULT"
        if skip:
            self._left_out.add(packet.pts)
        return packet

    def decoded(self, frame):
        """Placeholders (:class:`LeftOut`) to yield before ``frame``: the frames left out
        before it."""
        pts = frame.pts
        if pts is None:
            self.stop()
            return []
        return self._release(lambda earlier: earlier <= pts, pts)

    def remaining(self):
        """Placeholders for the frames left out after the last frame (call at the end)."""
        return self._release(lambda earlier: True, None)

    def _release(self, before, shown):
        placeholders = []
        while self._pending and before(self._pending[0]):
            earlier = self._pending.pop(0)
            if earlier == shown:
                self._left_out.discard(earlier)   # a reference picture flagged: decoded anyway
                break
            if earlier in self._left_out:
                self._left_out.discard(earlier)
                placeholders.append(LeftOut(earlier))
            elif shown is not None and self._needed is not None and not self._broken:
                # The decoder dropped a frame by itself: later indices are off.
                self.stop()
        self.left_out += len(placeholders)
        return placeholders
