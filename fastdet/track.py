"""Temporal logic for video: smoothing, frame skipping, patch tracking, stable ids.

:class:`VideoPipeline` turns a stream of frames into boxes with track ids.
Each temporal component is a small class, switched and tuned by the
``[track]`` section of the TOML configuration (:class:`TrackConfig`)::

    [track]
    every = 5                        # a full detection at least every 5th frame
    heat_smoothing = "exponential"   # or "fir" (mean of the last heat_frames maps) or "none"
    heat_alpha = 0.25                # new = (1 - alpha) * old + alpha * current
    box_frames = 4                   # box corners averaged over the last 4 measurements
    tracking = true                  # patch tracking between full detections

One frame goes through these steps:

1. With ``tracking``, every vehicle is looked for near its last position by
   the overlap of saturation masks with the patch it was first detected in
   (:class:`PatchModel`); the box moves with the best match, or the vehicle
   is *lost* when no placement overlaps more than ``min_patch_overlap``.
2. A full detection runs when ``every`` frames have passed since the last
   one (every frame by default without tracking), and with ``tracking`` also
   when no vehicle is tracked, one was lost, or the frame differs enough
   from the last fully searched one (:class:`SceneChangeTrigger`).
3. A full detection takes the detector's hits; with ``tracking``, hits
   entirely inside a tracked box are dropped (the vehicle is already known
   there), so only new vehicles are searched for.  Their heat is smoothed
   over frames (:class:`ExponentialHeat`, :class:`FirHeat`) and turned into
   boxes by the detector.
4. Boxes are associated with tracks (:class:`TrackTable`), so a vehicle
   keeps its id: without tracking by IoU; with tracking a new box lying
   mostly inside a tracked box (``merge_overlap``) is merged into it, and a
   box matching a lost vehicle revives its id.
5. Each track's box is the mean of its last ``box_frames`` measured boxes
   (:class:`BoxHistory`), so boxes do not jitter.
"""

from __future__ import annotations

import collections
import dataclasses
import math
import time
from dataclasses import dataclass

import numpy as np

from .config import read_toml
from .detect import as_bgr_frame
from .detections import Detections
from .errors import ConfigError, InputError
from .kernels.label import label_components
from .kernels.patch import (
    grey_thumbnail,
    mask_overlap_search,
    saturation_mask,
    sum_squared_difference,
)

HEAT_SMOOTHING = ("none", "exponential", "fir")


# -- configuration ------------------------------------------------------------
@dataclass(frozen=True)
class TrackConfig:
    """Settings of the temporal components (TOML section ``[track]``).

    Parameters
    ----------
    every : int, optional
        A full detection runs at least every ``every`` frames; the frames
        between reuse the last boxes, or the tracker's with ``tracking``.
        Default: every frame without ``tracking``; with it, only when a
        trigger fires.
    heat_smoothing : {'exponential', 'fir', 'none'}
        How heat maps are smoothed across full detections: an exponential
        filter ``new = (1 - heat_alpha) * old + heat_alpha * current`` (the
        default: a false hit in one frame rarely reaches the heat threshold);
        the mean of the last ``heat_frames`` maps; or not at all, which
        reports exactly what the detector finds in each frame.
    heat_alpha : float
        Weight of the current heat map in the exponential filter, in (0, 1].
    heat_frames : int
        Number of heat maps the FIR mean averages.
    box_frames : int
        A track's box is the corner-wise mean of its last ``box_frames``
        measured boxes; 1 disables box smoothing.
    match_iou : float
        Least intersection over union for a detection to continue a track
        (or, with ``tracking``, to revive a lost vehicle's id).
    max_missed : int
        Full detections a track may go unconfirmed before it is dropped;
        until then its id is kept for the vehicle's return.
    tracking : bool
        Track vehicles between full detections by patch matching, and run
        the full detector on the triggers described in the module notes.
    saturation_threshold : int
        HSV saturation (0-255) above which a pixel belongs to a patch mask.
    min_patch_overlap : float
        Least IoU of saturation masks for a patch to be found again.
    merge_overlap : float
        With ``tracking``, a new box with at least this fraction of its
        area inside a tracked box is merged into that vehicle; a box that
        only touches it is a new vehicle driving close by.
    min_patch_pixels : int
        A vehicle whose largest saturated region is smaller than this is
        not patch-tracked (it is re-detected every frame instead).
    search_radius : float
        Largest displacement between two frames that patch tracking looks
        for, in pixels of the detector's ``search.reference_size`` frame.
    scene_change_threshold : float
        A full detection runs when the mean squared grey-level difference
        between downsampled frames (the sum of squared differences over the
        pixel count) exceeds this, compared with the last fully searched
        frame.
    thumbnail_factor : int
        Downsampling factor of the frames the scene-change trigger compares.
    """

    every: int | None = None
    heat_smoothing: str = "exponential"
    heat_alpha: float = 0.25
    heat_frames: int = 5
    box_frames: int = 1
    match_iou: float = 0.2
    max_missed: int = 2
    tracking: bool = False
    saturation_threshold: int = 100
    min_patch_overlap: float = 0.5
    merge_overlap: float = 0.25
    min_patch_pixels: int = 64
    search_radius: float = 16.0
    scene_change_threshold: float = 400.0
    thumbnail_factor: int = 8

    def __post_init__(self):
        if self.every is not None:
            _integer("every", self.every, 1)
        if self.heat_smoothing not in HEAT_SMOOTHING:
            raise ConfigError(f"track.heat_smoothing must be one of {', '.join(HEAT_SMOOTHING)}, "
                              f"got {self.heat_smoothing!r}")
        _fraction("heat_alpha", self.heat_alpha, allow_zero=False)
        _integer("heat_frames", self.heat_frames, 1)
        _integer("box_frames", self.box_frames, 1)
        _fraction("match_iou", self.match_iou, allow_zero=False)
        _integer("max_missed", self.max_missed, 0)
        if not isinstance(self.tracking, bool):
            raise ConfigError(f"track.tracking must be true or false, got {self.tracking!r}")
        _integer("saturation_threshold", self.saturation_threshold, 0, 254)
        _fraction("min_patch_overlap", self.min_patch_overlap, allow_zero=True)
        _fraction("merge_overlap", self.merge_overlap, allow_zero=False)
        _integer("min_patch_pixels", self.min_patch_pixels, 1)
        _number("search_radius", self.search_radius, 0)
        _number("scene_change_threshold", self.scene_change_threshold, 0)
        _integer("thumbnail_factor", self.thumbnail_factor, 1, 256)

    @classmethod
    def from_dict(cls, data):
        """Build from the ``[track]`` table of a parsed TOML file.

        Raises
        ------
        ConfigError
            Naming the first unknown key or invalid value.
        """
        if not isinstance(data, dict):
            raise ConfigError("[track] must be a table")
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ConfigError(f"unknown key(s) in [track]: {', '.join(unknown)}")
        return cls(**data)

    @property
    def search_period(self):
        """Frames between forced full detections (``None``: triggers only)."""
        if self.every is not None:
            return self.every
        return None if self.tracking else 1

    def replace(self, **changes):
        """A copy with some settings changed (validated like the original)."""
        return dataclasses.replace(self, **changes)


def load_track_config(path=None):
    """The ``[track]`` settings of a TOML config file; defaults without one.

    Parameters
    ----------
    path : str or Path, optional
        The same file :func:`fastdet.config.load_config` reads; its other
        sections are left to that function.

    Returns
    -------
    TrackConfig
    """
    if path is None:
        return TrackConfig()
    return TrackConfig.from_dict(read_toml(path).get("track", {}))


def _number(name, value, low):
    if (isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value)
            or value < low):
        raise ConfigError(f"track.{name} must be a finite number >= {low}, got {value!r}")


def _integer(name, value, low, high=None):
    if (isinstance(value, bool) or not isinstance(value, int) or value < low
            or (high is not None and value > high)):
        bounds = f">= {low}" if high is None else f"in {low}..{high}"
        raise ConfigError(f"track.{name} must be an integer {bounds}, got {value!r}")


def _fraction(name, value, allow_zero):
    _number(name, value, 0)
    if value > 1 or (value == 0 and not allow_zero):
        interval = "[0, 1]" if allow_zero else "(0, 1]"
        raise ConfigError(f"track.{name} must be in {interval}, got {value!r}")


# -- box geometry -------------------------------------------------------------
def box_iou(a, b):
    """Pairwise intersection over union of two box arrays.

    Parameters
    ----------
    a : ndarray, shape (N, 4)
    b : ndarray, shape (M, 4)
        ``[x1, y1, x2, y2]``, ``x2``/``y2`` exclusive.

    Returns
    -------
    ndarray of float64, shape (N, M)
    """
    inter = box_intersection(a, b)
    area_a = _area(a)[:, None]
    area_b = _area(b)[None, :]
    union = area_a + area_b - inter
    return np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)


def box_intersection(a, b):
    """Pairwise intersection areas (float64, shape (N, M)) of two box arrays."""
    a = np.asarray(a, dtype=np.float64).reshape(-1, 4)
    b = np.asarray(b, dtype=np.float64).reshape(-1, 4)
    width = np.minimum(a[:, None, 2], b[None, :, 2]) - np.maximum(a[:, None, 0], b[None, :, 0])
    height = np.minimum(a[:, None, 3], b[None, :, 3]) - np.maximum(a[:, None, 1], b[None, :, 1])
    return np.clip(width, 0, None) * np.clip(height, 0, None)


def _area(boxes):
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    return (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])


def greedy_matches(scores, minimum):
    """Pairs ``(row, column)`` taken best-first, each row and column once.

    Parameters
    ----------
    scores : ndarray, shape (N, M)
        Higher is better (e.g. IoU).
    minimum : float
        Pairs scoring below this are never matched.

    Returns
    -------
    list of tuple of int
    """
    if scores.size == 0:
        return []
    rows, cols = np.nonzero(scores >= minimum)
    order = np.argsort(-scores[rows, cols], kind="stable")
    used_rows, used_cols, pairs = set(), set(), []
    for k in order:
        r, c = int(rows[k]), int(cols[k])
        if r not in used_rows and c not in used_cols:
            used_rows.add(r)
            used_cols.add(c)
            pairs.append((r, c))
    return pairs


# -- heat smoothing -------------------------------------------------------------
def _placed(heat, offset, shape):
    # The region slice of a map of `shape` that a region heat map covers.
    x, y = offset
    return slice(y, y + heat.shape[0]), slice(x, x + heat.shape[1])


class NoHeatSmoothing:
    """The current heat map, unchanged (``heat_smoothing = "none"``).

    Smoothers take the current heat over a region of the map (the detector
    computes it only around its hits) and return the whole smoothed map.
    """

    def update(self, heat, offset=(0, 0), shape=None):
        """The map to threshold for the current frame.

        Parameters
        ----------
        heat : ndarray of float32, shape (h, w)
            Current heat over a region of the map.
        offset : tuple of int
            ``(x, y)`` of that region in the map.
        shape : tuple of int, optional
            ``(height, width)`` of the map; ``heat.shape`` by default.  The
            region must lie inside it.

        Returns
        -------
        ndarray of float32, shape ``shape``
            Owned by the smoother: read it before the next update.
        """
        full = np.zeros(shape or heat.shape, dtype=np.float32)
        full[_placed(heat, offset, full.shape)] = heat
        return full

    def reset(self):
        """Forget past frames."""


class ExponentialHeat(NoHeatSmoothing):
    """Exponential filter: ``smoothed = (1 - alpha) * smoothed + alpha * current``.

    The first map after a reset is taken as is, so a vehicle present from the
    first frame is found in it rather than after the filter has warmed up.
    Only the decay touches the whole map; the current heat is added over its
    region alone.

    Parameters
    ----------
    alpha : float
        Weight of the current map, in (0, 1].
    """

    def __init__(self, alpha):
        self.alpha = float(alpha)
        self._state = None

    def update(self, heat, offset=(0, 0), shape=None):
        shape = tuple(shape or heat.shape)
        if self._state is None or self._state.shape != shape:
            self._state = super().update(heat, offset, shape)
        else:
            self._state *= np.float32(1.0 - self.alpha)
            self._state[_placed(heat, offset, shape)] += np.float32(self.alpha) * heat
        return self._state

    def reset(self):
        self._state = None


class FirHeat(NoHeatSmoothing):
    """Mean of the last ``frames`` heat maps (fewer right after a reset).

    A running sum keeps the cost at two map additions per frame whatever
    ``frames`` is; it is recomputed from the stored maps whenever the ring
    wraps so float rounding cannot accumulate.

    Parameters
    ----------
    frames : int
    """

    def __init__(self, frames):
        self.frames = int(frames)
        self.reset()

    def update(self, heat, offset=(0, 0), shape=None):
        shape = tuple(shape or heat.shape)
        if self._ring is None or self._ring.shape[1:] != shape:
            self._ring = np.zeros((self.frames,) + shape, dtype=np.float32)
            self._sum = np.zeros(shape, dtype=np.float32)
            self._count = self._next = 0
        slot = self._ring[self._next]
        self._sum -= slot
        slot[...] = 0.0
        slot[_placed(heat, offset, shape)] = heat
        self._sum += slot
        self._next = (self._next + 1) % self.frames
        self._count = min(self._count + 1, self.frames)
        if self._next == 0:
            np.sum(self._ring, axis=0, out=self._sum)
        return self._sum / np.float32(self._count)

    def reset(self):
        self._ring = None
        self._sum = None
        self._count = self._next = 0


def make_heat_smoother(config):
    """The heat smoother a :class:`TrackConfig` asks for."""
    if config.heat_smoothing == "exponential":
        return ExponentialHeat(config.heat_alpha)
    if config.heat_smoothing == "fir":
        return FirHeat(config.heat_frames)
    return NoHeatSmoothing()


# -- box smoothing --------------------------------------------------------------
class BoxHistory:
    """The last measured boxes of one vehicle; its box is their corner-wise mean.

    Parameters
    ----------
    frames : int
        How many measurements are averaged.
    """

    def __init__(self, frames):
        self._boxes = collections.deque(maxlen=int(frames))
        self._box = None

    def push(self, box):
        """Add the measurement of a new frame."""
        self._boxes.append(np.asarray(box, dtype=np.int32).copy())
        self._box = None

    def replace_last(self, box):
        """Correct the current frame's measurement."""
        self._boxes[-1] = np.asarray(box, dtype=np.int32).copy()
        self._box = None

    @property
    def box(self):
        """Smoothed ``[x1, y1, x2, y2]`` (int32)."""
        # Frames between detections ask again without new measurements.
        if self._box is None:
            mean = np.mean(self._boxes, axis=0)
            self._box = np.floor(mean + 0.5).astype(np.int32)
        return self._box.copy()


# -- patch tracking -------------------------------------------------------------
class PatchModel:
    """A vehicle's saturation mask, taken from the frame it was detected in.

    The mask is the largest connected region of saturated pixels of the
    detected patch, cropped to its bounding rectangle.  Later frames are
    always compared with this original mask, never with the last tracked
    patch, so a small error in one frame does not carry into the next.

    Parameters
    ----------
    mask : ndarray of uint8, shape (h, w)
        0/1 reference mask.
    origin : tuple of int
        ``(x, y)`` of the mask's top-left corner in the detection frame.
    """

    def __init__(self, mask, origin):
        self.mask = np.ascontiguousarray(mask, dtype=np.uint8)
        self.origin = (int(origin[0]), int(origin[1]))

    @classmethod
    def from_frame(cls, frame, box, threshold, min_pixels):
        """Take the model of the vehicle inside ``box``; ``None`` if it is too faint.

        Parameters
        ----------
        frame : ndarray of uint8, shape (H, W, 3)
        box : array_like of int
            ``[x1, y1, x2, y2]`` of the detection.
        threshold : int
            Saturation threshold.
        min_pixels : int
            Least size of the largest saturated region.
        """
        height, width = frame.shape[:2]
        x1, y1 = max(int(box[0]), 0), max(int(box[1]), 0)
        x2, y2 = min(int(box[2]), width), min(int(box[3]), height)
        if x2 <= x1 or y2 <= y1:
            return None
        mask = saturation_mask(np.ascontiguousarray(frame[y1:y2, x1:x2]), threshold)
        labels, count = label_components(mask, 8)
        if count == 0:
            return None
        sizes = np.bincount(labels.ravel(), minlength=count + 1)
        sizes[0] = 0
        largest = int(np.argmax(sizes))
        if sizes[largest] < min_pixels:
            return None
        rows = np.flatnonzero(np.any(labels == largest, axis=1))
        cols = np.flatnonzero(np.any(labels == largest, axis=0))
        top, bottom, left, right = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
        car = (labels[top:bottom, left:right] == largest).astype(np.uint8)
        return cls(car, (x1 + left, y1 + top))

    def locate(self, frame, position, radius, threshold):
        """Find the mask again near ``position``.

        Parameters
        ----------
        frame : ndarray of uint8, shape (H, W, 3)
        position : tuple of int
            ``(x, y)`` of the mask's top-left corner in the previous frame.
        radius : int
            Largest displacement looked for along each axis.
        threshold : int
            Saturation threshold.

        Returns
        -------
        position : tuple of int or None
            New ``(x, y)``; ``None`` if the mask no longer fits in the frame.
        overlap : float
            IoU of the reference mask with the frame's saturation mask there.
        """
        height, width = frame.shape[:2]
        mask_h, mask_w = self.mask.shape
        x, y = position
        # Only the area reachable within the radius is converted; placements
        # sticking out of the frame are not tried, so a vehicle driving out
        # of the picture loses overlap and is dropped.
        ax1, ay1 = max(x - radius, 0), max(y - radius, 0)
        ax2, ay2 = min(x + mask_w + radius, width), min(y + mask_h + radius, height)
        if ax2 - ax1 < mask_w or ay2 - ay1 < mask_h:
            return None, 0.0
        area = saturation_mask(np.ascontiguousarray(frame[ay1:ay2, ax1:ax2]), threshold)
        coarse = 2 if radius >= 4 else 1
        best_y, best_x, overlap = mask_overlap_search(self.mask, area, (y - ay1, x - ax1),
                                                      radius, coarse)
        if best_y < 0:
            return None, 0.0
        return (ax1 + best_x, ay1 + best_y), overlap


# -- scene change -----------------------------------------------------------------
class SceneChangeTrigger:
    """Says when a frame differs enough from the last fully searched one.

    Frames are compared as grey thumbnails (block means of ``factor x
    factor`` pixels) by their mean squared difference, so the threshold does
    not depend on the frame size.

    Parameters
    ----------
    threshold : float
        Mean squared grey-level difference above which the scene changed.
    factor : int
        Downsampling factor of the thumbnails.
    rows : tuple of int, optional
        ``(y1, y2)`` band of the frame compared (the detector's search
        band); the whole height by default.
    """

    def __init__(self, threshold, factor, rows=None):
        self.threshold = float(threshold)
        self.factor = int(factor)
        self.rows = rows
        self._reference = None
        #: Mean squared difference measured by the last :meth:`changed` call.
        self.last_difference = 0.0

    def thumbnail(self, frame):
        """The grey thumbnail frames are compared by (float32)."""
        band = frame if self.rows is None else frame[self.rows[0]:self.rows[1]]
        return grey_thumbnail(np.ascontiguousarray(band), self.factor)

    def set_reference(self, frame, thumbnail=None):
        """Remember ``frame`` as the last fully searched one.

        ``thumbnail``, if given, is ``self.thumbnail(frame)`` already computed.
        """
        self._reference = self.thumbnail(frame) if thumbnail is None else thumbnail

    def changed(self, frame, thumbnail=None):
        """True when ``frame`` differs from the reference by more than the threshold."""
        if self._reference is None:
            return True
        if thumbnail is None:
            thumbnail = self.thumbnail(frame)
        if thumbnail.shape != self._reference.shape or thumbnail.size == 0:
            return True
        self.last_difference = sum_squared_difference(thumbnail, self._reference) / thumbnail.size
        return self.last_difference > self.threshold


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
        pairs = greedy_matches(box_iou(self._boxes(self.tracks), detections.xyxy),
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
        inside = box_intersection(self._boxes(followed), boxes) / np.maximum(_area(boxes), 1)
        used = np.zeros(len(detections), dtype=bool)
        if followed:
            used = inside.max(axis=0) >= cfg.merge_overlap
        confirmed = set()
        for r, c in greedy_matches(box_iou(self._boxes(followed), everything.xyxy),
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
        pairs = greedy_matches(box_iou(self._boxes(lost), boxes[remaining]), cfg.match_iou)
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
            return Detections(np.zeros((0, 4), np.int32), np.zeros(0, np.float32),
                              np.zeros(0, np.int64))
        return Detections(np.stack([t.history.box for t in shown]), [t.score for t in shown],
                          [t.id for t in shown])

    @staticmethod
    def _boxes(tracks):
        if not tracks:
            return np.zeros((0, 4), np.int32)
        return np.stack([t.box for t in tracks]).astype(np.int32)


# -- the pipeline -------------------------------------------------------------------
class _Stopwatch:
    """Calls methods and sums the time they take."""

    def __init__(self):
        self.seconds = 0.0

    def __call__(self, method, *args):
        start = time.perf_counter()
        result = method(*args)
        self.seconds += time.perf_counter() - start
        return result


def hits_outside(hits, boxes):
    """The hits whose window is not entirely inside any of ``boxes``.

    Parameters
    ----------
    hits : fastdet.detect.Hits
    boxes : ndarray of int, shape (T, 4)

    Returns
    -------
    Hits
    """
    if len(boxes) == 0 or len(hits.scores) == 0:
        return hits
    h = hits.boxes[:, None, :]
    b = np.asarray(boxes)[None, :, :]
    inside = ((h[..., 0] >= b[..., 0]) & (h[..., 1] >= b[..., 1])
              & (h[..., 2] <= b[..., 2]) & (h[..., 3] <= b[..., 3]))
    keep = ~inside.any(axis=1)
    return dataclasses.replace(hits, boxes=hits.boxes[keep], scores=hits.scores[keep],
                               scale_index=hits.scale_index[keep])


class VideoPipeline:
    """Detection with temporal logic over a stream of frames.

    Parameters
    ----------
    detector : fastdet.Detector
        Anything with the detector's ``hits(frame)``,
        ``heat_region(hits, size)`` and ``boxes_from_heat(heat, origin,
        size)`` methods.
    config : TrackConfig, optional
        Temporal settings; defaults built in (detection on every frame,
        exponential heat smoothing, stable ids).

    Attributes
    ----------
    seconds : dict
        Time spent in ``"detect"`` (the detector's calls) and ``"track"``
        (everything temporal), summed over the frames processed.
    frames, full_searches : int
        Frames processed and how many of them were fully searched.

    Notes
    -----
    Frames must come in order; a change of frame size starts over (new
    tracks).  Frame indices are counted from ``first_index``.

    Examples
    --------
    >>> pipeline = VideoPipeline(Detector(), TrackConfig(every=5))   # doctest: +SKIP
    >>> capture = cv2.VideoCapture(0)                                # doctest: +SKIP
    >>> frames = iter(lambda: capture.read()[1], None)               # doctest: +SKIP
    >>> for index, frame, boxes, track_ids in pipeline(frames):      # doctest: +SKIP
    ...     print(index, boxes.tolist(), track_ids.tolist())
    """

    def __init__(self, detector, config=None):
        self.detector = detector
        self.config = config or TrackConfig()
        self.reset()

    def reset(self):
        """Forget all temporal state (tracks, smoothed heat, counters)."""
        self._tracks = TrackTable(self.config)
        self._heat = make_heat_smoother(self.config)
        self._since_full = None
        self._size = None
        self.seconds = {"detect": 0.0, "track": 0.0}
        self.last_heat = None
        self.frames = 0
        self.full_searches = 0

    def __call__(self, frames, first_index=0):
        """Process an iterable of frames lazily.

        Parameters
        ----------
        frames : iterable of ndarray
            BGR uint8 frames (grey and BGRA accepted), in order.
        first_index : int
            Index of the first frame (e.g. the ``--start`` frame of a video).

        Yields
        ------
        frame_index : int
        frame : ndarray
            The frame as given.
        boxes : ndarray of int32, shape (N, 4)
            ``[x1, y1, x2, y2]``, ``x2``/``y2`` exclusive.
        track_ids : ndarray of int64, shape (N,)
        """
        for offset, frame in enumerate(frames):
            detections = self.process(frame)
            yield first_index + offset, frame, detections.xyxy, detections.track_id

    run = __call__

    @property
    def wants_frame(self):
        """Whether the next :meth:`process` call looks at the frame's pixels.

        It does not between periodic full detections without tracking; a
        caller may then pass ``None`` instead of decoding the frame (e.g.
        ``cv2.VideoCapture.grab`` without ``retrieve``).
        """
        return self.config.tracking or self._search_due()

    def _search_due(self):
        # The periodic schedule only; tracking adds its triggers on top.
        period = self.config.search_period
        return self._since_full is None or (period is not None
                                            and self._since_full + 1 >= period)

    def process(self, frame):
        """Process the next frame of the stream.

        Parameters
        ----------
        frame : ndarray or None
            BGR uint8 frame (grey and BGRA accepted); ``None`` is allowed
            when :attr:`wants_frame` is False.

        Returns
        -------
        Detections
            With ``track_id`` set.
        """
        start = time.perf_counter()
        if frame is None:
            if self.wants_frame:
                raise InputError("this frame is needed (a full detection or tracking is due)")
            self._since_full += 1
            self.frames += 1
            detections = self._tracks.visible()
            self.seconds["track"] += time.perf_counter() - start
            return detections
        frame = as_bgr_frame(frame)
        size = (frame.shape[1], frame.shape[0])
        if size != self._size:
            self._start_stream(size)
        cfg = self.config
        search = self._search_due()
        thumbnail = None
        if cfg.tracking:
            lost = self._tracks.follow(frame, self._radius) if self._tracks.tracks else False
            no_vehicle = not any(not t.lost for t in self._tracks.tracks)
            search = search or lost or no_vehicle
            if not search:
                thumbnail = self._scene.thumbnail(frame)
                search = self._scene.changed(frame, thumbnail)
        detect_seconds = 0.0
        if search:
            detect_seconds = self._full_search(frame, size, thumbnail)
            self._since_full = 0
            self.full_searches += 1
        else:
            self._since_full += 1
        detections = self._tracks.visible()
        self.frames += 1
        self.seconds["detect"] += detect_seconds
        self.seconds["track"] += time.perf_counter() - start - detect_seconds
        return detections

    # -- internals ------------------------------------------------------------------
    def _start_stream(self, size):
        # A new frame size is a new stream: no track or heat carries over,
        # but ids keep counting up so they stay unique for this pipeline.
        self._tracks.reset()
        self._heat.reset()
        self._since_full = None
        self._size = size
        width, height = size
        self._band = (0, 0, width, height)
        plans = getattr(self.detector, "plans", None)
        if plans is not None:
            rois = [plan.roi for plan in plans(size)]
            if rois:
                # Heat is only ever non-zero where some scale searches.
                self._band = (min(r[0] for r in rois), min(r[1] for r in rois),
                              max(r[2] for r in rois), max(r[3] for r in rois))
        # Like the detector's scales, the radius is given for its reference
        # frame size (a detector without one: for the frame itself).
        search_config = getattr(getattr(self.detector, "config", None), "search", None)
        ref_w, ref_h = getattr(search_config, "reference_size", size)
        scale = math.sqrt(width / ref_w * height / ref_h)
        self._radius = int(round(self.config.search_radius * scale))
        self._scene = SceneChangeTrigger(self.config.scene_change_threshold,
                                         self.config.thumbnail_factor,
                                         rows=(self._band[1], self._band[3]))

    def _full_search(self, frame, size, thumbnail=None):
        """Detect, smooth, associate; returns the seconds spent in the detector."""
        detector = self.detector
        in_detector = _Stopwatch()
        hits = in_detector(detector.hits, frame)
        if not self.config.tracking:
            self._tracks.associate(self._detect(hits, size, in_detector), frame)
            return in_detector.seconds
        tracked = self._tracks.tracked_boxes()
        everything = Detections.empty()
        if len(tracked):
            # The detector's own view, from all hits and unsmoothed, confirms
            # and refits the followed vehicles independently of the tracker.
            heat, origin = in_detector(detector.heat_region, hits, size)
            everything = in_detector(detector.boxes_from_heat, heat, origin, size)
        # New vehicles are searched for outside the tracked boxes only.
        detections = self._detect(hits_outside(hits, tracked), size, in_detector)
        self._tracks.merge(detections, everything, frame)
        self._scene.set_reference(frame, thumbnail)
        return in_detector.seconds

    def _detect(self, hits, size, in_detector):
        heat, origin = in_detector(self.detector.heat_region, hits, size)
        heat, origin = self._smoothed_heat(heat, origin)   # the tracker's time
        #: The smoothed heat over a region of the last fully searched frame, and its origin.
        self.last_heat = (heat, origin)
        return in_detector(self.detector.boxes_from_heat, heat, origin, size)

    def _smoothed_heat(self, heat, origin):
        if self.config.heat_smoothing == "none":
            return heat, origin
        # Smoothing needs the same pixels every frame: the whole search band.
        bx1, by1, bx2, by2 = self._band
        x1, y1 = max(origin[0], bx1), max(origin[1], by1)
        x2 = min(origin[0] + heat.shape[1], bx2)
        y2 = min(origin[1] + heat.shape[0], by2)
        region = np.zeros((0, 0), np.float32)
        if x2 > x1 and y2 > y1:
            region = heat[y1 - origin[1]:y2 - origin[1], x1 - origin[0]:x2 - origin[0]]
        else:
            x1, y1 = bx1, by1
        smoothed = self._heat.update(region, (x1 - bx1, y1 - by1), (by2 - by1, bx2 - bx1))
        return smoothed, (bx1, by1)
