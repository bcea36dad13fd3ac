"""Is a segment boundary exact?  And which id does each segment's vehicle get in the whole video?

A segment after the first starts with a warm-up: frames before its start,
processed and discarded, so that its pipeline reaches the boundary in the
state the whole-video run has there.  :func:`compare` decides from the
digests of :mod:`fastdet.batch.state` whether it did; only then are the
segment's outputs those of the whole-video run.

Why a flushed comparison of the exponential heat is enough
----------------------------------------------------------
With ``smoothed = (1 - alpha) * smoothed + alpha * heat`` in float32, heat
from before the warm-up never quite leaves the whole-video run's map: it
decays and, below float32's normal range, sticks at one or two subnormal
units.  The warm-up's map has exactly 0 there.  Let ``a`` and ``b`` be such
a pixel in the two maps, both below a level ``E``:

* if no heat arrives at the pixel, both only decay and stay below ``E``;
* if heat arrives, the map adds ``c = alpha * heat`` to ``(1 - alpha) * a``
  (and to ``(1 - alpha) * b``), both below ``E``.  When ``E`` is at most half
  the spacing of float32 numbers at ``c``, both sums round to exactly ``c``:
  the pixel is identical from then on.

So if the two maps agree exactly wherever either of them reaches ``E``, they
agree exactly, or both lie below ``E``, at every later frame too.  Every
output (thresholding at ``heat.threshold``, the blobs, their peaks and
splits) reads only pixels above the threshold; with ``E <= threshold`` the
pixels below ``E`` change nothing.  ``E`` therefore has to be at most the
heat threshold and at most half the float32 spacing at ``alpha`` times the
smallest positive heat of any frame from the boundary on, which the segments
measure as they go (``heat_floor``).  The digests are taken at levels
``E = 2**-j``; the coarsest admissible one is compared.

The tracks must agree position by position in the table: their order
decides ties in association.  When they agree only up to order (the warm-up
met long-followed vehicles in another order than the whole video did) the
segment is run again with its tables put in the right order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .state import FLUSH_LEVELS


@dataclass(frozen=True)
class Verdict:
    """The outcome of comparing the two sides of a boundary.

    Attributes
    ----------
    exact : bool
        The segment after the boundary reproduces the whole-video run.
    order : list of int or None
        When the states agree but for the order of the tracks: the
        permutation that puts the later segment's table in the earlier one's
        order (:func:`fastdet.batch.state.reorder_tracks`).
    reason : str
        What differed (empty when exact).
    """

    exact: bool
    order: list | None = None
    reason: str = ""


def flush_level(heat_threshold, alpha, heat_floor):
    """The coarsest flush level ``j`` (``E = 2**-j``) at which two heat maps may be compared.

    Parameters
    ----------
    heat_threshold : float
        ``heat.threshold`` of the detector.
    alpha : float
        ``track.heat_alpha``.
    heat_floor : float
        Smallest positive heat of any frame from the boundary on (``inf``
        when no frame had any).

    Returns
    -------
    int or None
        ``None`` when no level is fine enough (the boundary cannot be certified).
    """
    limit = float(heat_threshold)
    if math.isfinite(heat_floor):
        smallest_step = np.float32(alpha) * np.float32(heat_floor)
        limit = min(limit, float(np.spacing(np.float32(smallest_step))) / 2)
    for level in FLUSH_LEVELS:
        if 2.0 ** -level <= limit:
            return level
    return None


def compare(previous_end, start, heat_threshold, heat_floor):
    """Whether the state a segment starts from is the one the segment before it ends in.

    Parameters
    ----------
    previous_end, start : dict
        :func:`fastdet.batch.state.pipeline_state` of the earlier segment
        after its last frame and of the later one after its warm-up.
    heat_threshold : float
    heat_floor : float
        See :func:`flush_level`.

    Returns
    -------
    Verdict
    """
    if previous_end["frame"] is None or previous_end["frame"] != start["frame"]:
        return Verdict(False, reason="the frames before the boundary differ")
    if previous_end["scalars"] != start["scalars"]:
        return Verdict(False, reason="the search schedule or scene reference differs")
    reason = _heat_difference(previous_end["heat"], start["heat"], heat_threshold, heat_floor)
    if reason:
        return Verdict(False, reason=reason)
    before, after = previous_end["tracks"], start["tracks"]
    if before == after:
        return Verdict(True)
    if sorted(before) == sorted(after) and len(set(after)) == len(after):
        return Verdict(False, order=[after.index(d) for d in before],
                       reason="the tracks are in another order")
    return Verdict(False, reason="the tracks differ")


def _heat_difference(before, after, heat_threshold, heat_floor):
    if before["kind"] != after["kind"] or before["kind"] == "unknown":
        return "the heat smoothing cannot be compared"
    if before["kind"] == "exact":
        return "" if before["digest"] == after["digest"] else "the heat maps differ"
    if before["alpha"] != after["alpha"]:
        return "the heat smoothing differs"
    if before["levels"] is None or after["levels"] is None:
        return "" if before["levels"] is after["levels"] else "only one side has heat"
    level = flush_level(heat_threshold, before["alpha"], heat_floor)
    if level is None:
        return "the heat threshold or the smallest heat leaves no margin"
    return "" if before["levels"][level] == after["levels"][level] else "the heat maps differ"


@dataclass(frozen=True)
class IdMap:
    """Track ids of one segment -> ids of the whole video.

    Vehicles in the segment's table at its start continue the previous
    segment's vehicles at the same table positions; vehicles found later get
    the ids the whole-video run gives them, shifted by the difference of the
    two runs' next ids at the boundary.
    """

    continued: dict
    first_new: int
    shift: int

    @classmethod
    def identity(cls):
        return cls({}, 1, 0)

    @classmethod
    def across(cls, previous_ids, previous_next_id, start):
        """The map of a segment whose ``start`` state was certified against the previous end.

        ``previous_ids`` and ``previous_next_id`` are the previous segment's
        table ids and next id after its last frame, already in whole-video ids.
        """
        return cls(dict(zip(start["ids"], previous_ids)), start["next_id"],
                   previous_next_id - start["next_id"])

    def __call__(self, track_id):
        track_id = int(track_id)
        if track_id in self.continued:
            return self.continued[track_id]
        if track_id < self.first_new:
            raise ValueError(f"track {track_id} was neither carried over nor new")
        return track_id + self.shift

    def end_ids(self, end):
        """The table ids and the next id at the segment's end, in whole-video ids."""
        return [self(i) for i in end["ids"]], end["next_id"] + self.shift

    def to_dict(self):
        return {"continued": {str(k): v for k, v in self.continued.items()},
                "first_new": self.first_new, "shift": self.shift}

    @classmethod
    def from_dict(cls, data):
        return cls({int(k): int(v) for k, v in data["continued"].items()},
                   int(data["first_new"]), int(data["shift"]))
