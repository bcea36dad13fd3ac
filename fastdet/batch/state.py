"""Digests of a :class:`~fastdet.video.pipeline.VideoPipeline`'s temporal state at a frame boundary.

A long video is cut into segments that run on different workers; each one
first re-processes some frames before its start (a warm-up) so that its
pipeline arrives at the boundary in the state the whole-video run has there.
Whether it did is *checked*, not hoped: the segment before reports the state
it ends in, the segment after the state its warm-up reached, and
:mod:`fastdet.batch.boundary` compares the two.  This module turns a
pipeline's state into the small digests that travel back to the client:

* ``scalars``: frames since the last full search, the frame size, the scene
  trigger's reference thumbnail;
* ``heat``: the smoothed heat map.  For exponential smoothing, one digest per
  *flush level* ``2**-j`` of the pixels at or above ``2**-j`` (see
  :mod:`fastdet.batch.boundary` for why values below cannot change any later
  output); for FIR smoothing the ring of maps, exactly;
* ``tracks``: one digest per track, in table order, of everything but its id
  (box, score, misses, box history, patch); the ids and the next id to be
  given out travel as they are, to stitch ids across the boundary;
* ``frame``: index and digest of the last frame read, so that a reader which
  seeks inexactly cannot go unnoticed.

This is the one module that reads ``VideoPipeline``'s private attributes (a
test pins them); the video layer should offer such a snapshot itself.
"""

from __future__ import annotations

import hashlib

import numpy as np

from ..video.smoothing import ExponentialHeat, FirHeat, NoHeatSmoothing

#: Flush levels ``2**-j`` of the exponential heat digests (2**-148 is the
#: smallest power of two above float32's smallest subnormal).
FLUSH_LEVELS = tuple(range(0, 150, 2))


def _digest(*parts):
    digest = hashlib.blake2b(digest_size=16)
    for part in parts:
        if isinstance(part, np.ndarray):
            digest.update(str((part.dtype.str, part.shape)).encode())
            digest.update(np.ascontiguousarray(part).tobytes())
        else:
            digest.update(repr(part).encode())
        digest.update(b"\x00")
    return digest.hexdigest()


def frame_digest(frame):
    """Digest of a decoded frame's pixels."""
    return _digest(np.asarray(frame))


def heat_state(smoother):
    """Digests of a heat smoother's state (see the module notes)."""
    if isinstance(smoother, ExponentialHeat):
        state = smoother._state
        levels = None if state is None else flushed_digests(state)
        return {"kind": "exponential", "alpha": smoother.alpha, "levels": levels}
    if isinstance(smoother, FirHeat):
        return {"kind": "exact", "digest": _digest("fir", smoother._ring, smoother._sum,
                                                   smoother._count, smoother._next)}
    if type(smoother) is NoHeatSmoothing:
        return {"kind": "exact", "digest": _digest("none")}
    return {"kind": "unknown"}        # never certified: the segment is redone from frame 0


def flushed_digests(heat):
    """``{j: digest}``: for each flush level ``E = 2**-j``, a digest of the map's pixels >= ``E``.

    Two maps have equal digests at level ``j`` exactly when they agree at
    every pixel where either reaches ``E`` (the digest covers the pixels'
    positions and values).  The pixels are sorted once by value, so each
    level's pixels are a prefix of that order and all levels cost one pass.
    """
    flat = heat.ravel()
    positions = np.flatnonzero(flat >= np.float32(2.0 ** -FLUSH_LEVELS[-1]))
    values = flat[positions]
    order = np.lexsort((positions, -values))          # largest first, ties by position
    pixels = np.empty(len(order), dtype=[("position", "<i8"), ("value", "<f4")])
    pixels["position"], pixels["value"] = positions[order], values[order]
    descending = -pixels["value"]
    digest = hashlib.blake2b(repr(heat.shape).encode(), digest_size=16)
    levels, done = {}, 0
    for level in FLUSH_LEVELS:                        # E falls, the prefix grows
        count = int(np.searchsorted(descending, -np.float32(2.0 ** -level), side="right"))
        digest.update(pixels[done:count].tobytes())
        done = count
        levels[level] = digest.copy().hexdigest()
    return levels


def track_digest(track):
    """Digest of one track's state, its id left out."""
    patch = track.patch
    return _digest(np.asarray(track.box, np.int32), float(track.score), int(track.missed),
                   bool(track.lost), np.asarray(list(track.history._boxes), np.int32).reshape(-1, 4),
                   None if patch is None else patch.mask, None if patch is None else patch.origin,
                   track.patch_position)


def pipeline_state(pipeline, last_frame=None):
    """The digests of ``pipeline``'s temporal state before its next frame.

    Parameters
    ----------
    pipeline : VideoPipeline
    last_frame : tuple of (int, str), optional
        Index and :func:`frame_digest` of the last frame processed.

    Returns
    -------
    dict
        ``scalars``, ``heat``, ``tracks`` (digests in table order), ``ids``
        (track ids in the same order), ``next_id`` and ``frame``.
    """
    scene = getattr(pipeline, "_scene", None)
    reference = None if scene is None else scene._reference
    table = pipeline._tracks
    return {
        "scalars": _digest(pipeline._since_full, pipeline._size, reference),
        "heat": heat_state(pipeline._heat),
        "tracks": [track_digest(t) for t in table.tracks],
        "ids": [int(t.id) for t in table.tracks],
        "next_id": int(table._next_id),
        "frame": None if last_frame is None else list(last_frame),
    }


def reorder_tracks(pipeline, order):
    """Put the pipeline's tracks in ``order`` (a permutation of table positions).

    A segment's warm-up creates the vehicles it finds on its first frame in
    the order the detector lists them, while the whole-video run created them
    in the order they appeared; the order decides ties in association, so a
    boundary is only exact once the tables agree position by position.
    """
    tracks = pipeline._tracks.tracks
    if sorted(order) != list(range(len(tracks))):
        raise ValueError(f"{order} is not a permutation of {len(tracks)} tracks")
    pipeline._tracks.tracks = [tracks[i] for i in order]
