"""The track table: which box is which vehicle, frame after frame.

Without patch tracking, boxes continue tracks by IoU; with it, vehicles are
followed between full detections by :class:`~fastdet.video.patch.PatchModel`
and a full detection confirms, refits, revives or adds them
(:meth:`TrackTable.merge`).  Ids are never reused.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..detector.detections import Detections
from ..detector.geometry import box_areas, intersection_matrix, iou_rows
from .patch import PatchModel
from .smoothing import BoxHistory


def greedy_matches(scores, minimum):
    """Pairs ``(row, column)`` taken best-first, each row and column once.

    Parameters
    ----------
    scores : ndarray, shape (N, M), or list of N lists of M floats
        Higher is better (e.g. IoU).
    minimum : float
        Pairs scoring below this are never matched.

    Returns
    -------
    list of tuple of int
    """
    if isinstance(scores, np.ndarray):
        scores = scores.tolist()
    # Plain Python over the few boxes of a frame (a handful of NumPy calls cost
    # more); a stable sort, so ties go in row-major order.
    candidates = sorted(((value, r, c) for r, row in enumerate(scores)
                         for c, value in enumerate(row) if value >= minimum),
                        key=lambda candidate: -candidate[0])
    used_rows, used_cols, pairs = set(), set(), []
    for _, r, c in candidates:
        if r not in used_rows and c not in used_cols:
            used_rows.add(r)
            used_cols.add(c)
            pairs.append((r, c))
    return pairs


# -- tracks -------------------------------------------------------------------------
@dataclass(eq=False)
class Track:
    """One vehicle followed across frames.

    Attributes
    ----------
    id : int
        Stable identity.
    box : ndarray of int32, shape (4,)
        Last measured box (unsmoothed).
    score : float
        Score of the last detection that confirmed it.
    history : BoxHistory
        Recent measured boxes; ``history.box`` is what is reported.
    missed : int
        Full detections since the last one that confirmed the track.
    patch : PatchModel or None
        Saturation mask for patch tracking (``None`` when too faint).
    patch_position : tuple of int or None
        ``(x, y)`` of the patch mask in the current frame.
    lost : bool
        Patch tracking failed this frame; a full detection may revive it.
    """

    id: int
    box: np.ndarray
    score: float
    history: BoxHistory
    missed: int = 0
    patch: PatchModel | None = None
    patch_position: tuple | None = None
    lost: bool = False

    def measure(self, box, score=None):
        """Record this frame's measured box."""
        self.box = np.asarray(box, dtype=np.int32).copy()
        self.history.push(self.box)
        if score is not None:
            self.score = float(score)

    def move(self, dx, dy):
        """Shift the box by a displacement patch tracking found."""
        self.measure(self.box + np.array([dx, dy, dx, dy], dtype=np.int32))


class TrackTable:
    """The current tracks and the rules that keep each vehicle's id.

    Parameters
    ----------
    config : TrackConfig
    """

    def __init__(self, config):
        self.config = config
        self.tracks = []
        self._next_id = 1

    def reset(self):
        """Drop every track (ids keep increasing, so none is ever reused)."""
        self.tracks = []

    def _new_track(self, box, score, frame):
        track = Track(self._next_id, np.asarray(box, np.int32), float(score),
                      BoxHistory(self.config.box_frames))
        self._next_id += 1
        track.measure(box)
        if self.config.tracking:
            self._attach_patch(track, frame)
        self.tracks.append(track)
        return track

    def _attach_patch(self, track, frame):
        cfg = self.config
        track.patch = PatchModel.from_frame(frame, track.box, cfg.saturation_threshold,
                                            cfg.min_patch_pixels)
        track.patch_position = None if track.patch is None else track.patch.origin

    # -- association without patch tracking ------------------------------------
    def associate(self, detections, frame):
        """Continue tracks with the detections of a fully searched frame (by IoU)."""
        pairs = greedy_matches(iou_rows(self._box_rows(self.tracks), detections.xyxy.tolist()),
                               self.config.match_iou)
        matched_tracks = {r for r, _ in pairs}
        matched_dets = {c for _, c in pairs}
        for r, c in pairs:
            track = self.tracks[r]
            track.measure(detections.xyxy[c], detections.score[c])
            track.missed = 0
        for r, track in enumerate(self.tracks):
            if r not in matched_tracks:
                track.missed += 1
        self.tracks = [t for t in self.tracks if t.missed <= self.config.max_missed]
        for c in range(len(detections)):
            if c not in matched_dets:
                self._new_track(detections.xyxy[c], detections.score[c], frame)

    # -- patch tracking ----------------------------------------------------------
    def follow(self, frame, radius):
        """Move every tracked vehicle to where its patch is found; mark the rest lost.

        Returns
        -------
        bool
            True when a vehicle was lost.
        """
        cfg = self.config
        any_lost = False
        for track in self.tracks:
            if track.lost:
                continue
            position, overlap = (None, 0.0)
            if track.patch is not None:
                position, overlap = track.patch.locate(frame, track.patch_position, radius,
                                                       cfg.saturation_threshold)
            if position is None or overlap <= cfg.min_patch_overlap:
                track.lost = True
                any_lost = True
                continue
            dx = position[0] - track.patch_position[0]
            dy = position[1] - track.patch_position[1]
            track.patch_position = position
            track.move(dx, dy)
        return any_lost

    def tracked_boxes(self):
        """Boxes (int32, (N, 4)) of the vehicles currently followed, not lost."""
        return self._boxes([t for t in self.tracks if not t.lost])

    def merge(self, detections, everything, frame):
        """Fold a full detection's results into the tracks, with patch tracking.

        Parameters
        ----------
        detections : Detections
            Boxes found from the hits outside the tracked boxes: candidates
            for new vehicles.
        everything : Detections
            Boxes found from all the hits.  A followed vehicle that one of
            them matches (IoU >= ``match_iou``) is confirmed and takes that
            box, so its box follows the vehicle's size; one that none
            matches is unconfirmed, and dropped after ``max_missed`` such
            searches, so tracking cannot keep a false detection alive.
        frame : ndarray
            The frame, for the patches of new or revived vehicles.
        """
        cfg = self.config
        followed = [t for t in self.tracks if not t.lost]
        lost = [t for t in self.tracks if t.lost]
        boxes = detections.xyxy
        # A new box lying mostly inside a box that was searched around is
        # more of that vehicle (whose box is refitted below), not a new one.
        followed_boxes = self._boxes(followed)
        inside = intersection_matrix(followed_boxes, boxes) / np.maximum(box_areas(boxes), 1)
        used = np.zeros(len(detections), dtype=bool)
        if followed:
            used = inside.max(axis=0) >= cfg.merge_overlap
        confirmed = set()
        for r, c in greedy_matches(iou_rows(followed_boxes.tolist(), everything.xyxy.tolist()),
                                   cfg.match_iou):
            track = followed[r]
            track.box = everything.xyxy[c].copy()
            track.history.replace_last(track.box)
            track.score = float(everything.score[c])
            confirmed.add(r)
        for r, track in enumerate(followed):
            track.missed = 0 if r in confirmed else track.missed + 1
        # A lost vehicle found again keeps its id, with a fresh patch.
        remaining = np.flatnonzero(~used)
        pairs = greedy_matches(iou_rows(self._box_rows(lost), boxes[remaining].tolist()),
                               cfg.match_iou)
        for r, k in pairs:
            c = remaining[k]
            track = lost[r]
            track.measure(boxes[c], detections.score[c])
            track.lost = False
            track.missed = 0
            self._attach_patch(track, frame)
            used[c] = True
        revived = {r for r, _ in pairs}
        for r, track in enumerate(lost):
            if r not in revived:
                track.missed += 1
        self.tracks = [t for t in self.tracks if t.missed <= cfg.max_missed]
        for c in np.flatnonzero(~used):
            self._new_track(boxes[c], detections.score[c], frame)

    # -- output -----------------------------------------------------------------
    def visible(self):
        """Detections of the tracks to report this frame, ordered by id.

        A track is reported while the last full detection confirmed it (and
        patch tracking has not lost it since); an unconfirmed one is only
        kept, hidden, so that its id survives a short miss.
        """
        shown = sorted((t for t in self.tracks if t.missed == 0 and not t.lost),
                       key=lambda t: t.id)
        if not shown:
            return Detections.of_valid(np.zeros((0, 4), np.int32), np.zeros(0, np.float32),
                                       np.zeros(0, np.int64))
        # Smoothed boxes are means of valid int32 boxes: valid int32 boxes.
        return Detections.of_valid(np.array([t.history.box for t in shown], np.int32),
                                   np.array([t.score for t in shown], np.float32),
                                   np.array([t.id for t in shown], np.int64))

    @staticmethod
    def _box_rows(tracks):
        return [t.box.tolist() for t in tracks]

    @staticmethod
    def _boxes(tracks):
        if not tracks:
            return np.zeros((0, 4), np.int32)
        return np.array([t.box for t in tracks], np.int32)
