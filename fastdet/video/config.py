"""Settings of the temporal components: the ``[track]`` section of a TOML config."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from ..detector.config import read_toml
from ..detector.plain import plain_numbers
from ..errors import ConfigError

HEAT_SMOOTHING = ("none", "exponential", "fir")
#: Upper bounds of settings whose size is memory or pixels: beyond them a run
#: ran out of memory or overflowed a kernel's arguments.  100 frames of heat
#: are 4 s at 25 fps (and 350 MB at 1280x720).
MAX_HEAT_FRAMES = 100
MAX_BOX_FRAMES = 1000
MAX_SEARCH_RADIUS = 10000.0


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
        plain_numbers(self)
        if self.every is not None:
            _integer("every", self.every, 1)
        if self.heat_smoothing not in HEAT_SMOOTHING:
            raise ConfigError(f"track.heat_smoothing must be one of {', '.join(HEAT_SMOOTHING)}, "
                              f"got {self.heat_smoothing!r}")
        _fraction("heat_alpha", self.heat_alpha, allow_zero=False)
        # Bounded: the FIR keeps heat_frames maps, each box its last box_frames.
        _integer("heat_frames", self.heat_frames, 1, MAX_HEAT_FRAMES)
        _integer("box_frames", self.box_frames, 1, MAX_BOX_FRAMES)
        _fraction("match_iou", self.match_iou, allow_zero=False)
        _integer("max_missed", self.max_missed, 0)
        if not isinstance(self.tracking, bool):
            raise ConfigError(f"track.tracking must be true or false, got {self.tracking!r}")
        _integer("saturation_threshold", self.saturation_threshold, 0, 254)
        _fraction("min_patch_overlap", self.min_patch_overlap, allow_zero=True)
        _fraction("merge_overlap", self.merge_overlap, allow_zero=False)
        _integer("min_patch_pixels", self.min_patch_pixels, 1)
        _number("search_radius", self.search_radius, 0, MAX_SEARCH_RADIUS)
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
        # str: a key that is not one (from_dict({1: 2})) cannot be sorted or joined.
        unknown = sorted(str(key) for key in set(data) - known)
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
        The same file :func:`fastdet.detector.config.load_config` reads; its other
        sections are left to that function.

    Returns
    -------
    TrackConfig

    Raises
    ------
    ConfigError
        Naming the file and the first unknown key or invalid value.
    """
    if path is None:
        return TrackConfig()
    try:
        return TrackConfig.from_dict(read_toml(path).get("track", {}))
    except ConfigError as exc:
        if str(path) in str(exc):
            raise
        raise ConfigError(f"{path}: {exc}") from None


def _number(name, value, low, high=None):
    if (isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value)
            or value < low or (high is not None and value > high)):
        bounds = f">= {low}" if high is None else f"in {low}..{high:g}"
        raise ConfigError(f"track.{name} must be a finite number {bounds}, got {value!r}")


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
