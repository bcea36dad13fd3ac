"""Detector configuration: dataclasses with built-in defaults, overridable from TOML.

A TOML file only lists what it changes::

    [search]
    decision_threshold = 0.3

    [[search.scales]]          # giving scales replaces the whole list
    window = 64
    overlap = 0.5
    x = [0, 1280]
    y = [380, 660]

    [heat]
    threshold = 2

    [boxes]
    min_size = 24

Unknown sections or keys are rejected with their name.  Coordinates are in
pixels of a ``search.reference_size`` frame (1280x720) and scaled
proportionally for other frame sizes.

The default thresholds and box-shape correction are the ones ``fastdet tune``
chose for the bundled model on the annotated frames of the test video
(``tools/build_default_model.py``); the test images play no part in them.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib

from ..errors import ConfigError


def _is_number(value):
    """A finite int or float (bools, which are ints, are not numbers here)."""
    return (isinstance(value, (int, float)) and not isinstance(value, bool)
            and math.isfinite(value))


def _number(name, value):
    if not _is_number(value):
        raise ConfigError(f"{name} must be a finite number, got {value!r}")


@dataclass(frozen=True)
class ScaleConfig:
    """One search scale.

    Parameters
    ----------
    window : float
        Window side in reference-frame pixels.
    overlap : float
        Fraction in [0, 1) by which neighbouring windows overlap; the step is
        rounded to whole HOG cells.
    x, y : tuple of float
        ``[start, stop)`` of the region searched, in reference-frame pixels.
    """

    window: float
    overlap: float
    x: tuple
    y: tuple

    def __post_init__(self):
        object.__setattr__(self, "x", tuple(self.x))
        object.__setattr__(self, "y", tuple(self.y))
        _number("search.scales.window", self.window)
        if not self.window >= 8:
            raise ConfigError(f"search.scales.window must be a number >= 8, got {self.window!r}")
        _number("search.scales.overlap", self.overlap)
        if not 0 <= self.overlap < 1:
            raise ConfigError(f"search.scales.overlap must be in [0, 1), got {self.overlap!r}")
        for name in ("x", "y"):
            span = getattr(self, name)
            if (len(span) != 2 or not all(_is_number(v) for v in span)
                    or not span[0] < span[1]):
                raise ConfigError(f"search.scales.{name} must be [start, stop] with start < stop, "
                                  f"got {list(span)!r}")


#: The five scales of the published pipeline this project starts from
#: (``fastdet/data/published_search.toml`` restores them).
PUBLISHED_SCALES = (
    ScaleConfig(32, 0.0, (320, 960), (396, 460)),
    ScaleConfig(48, 0.5, (0, 1280), (360, 540)),
    ScaleConfig(64, 0.5, (426, 853), (396, 648)),
    ScaleConfig(112, 0.75, (0, 1280), (360, 630)),
    ScaleConfig(128, 0.75, (0, 1280), (360, 630)),
)

#: The default search: the published scales with the 64-pixel one moved.
#: Published, it covers only the middle third of the frame (x 426-853) with a
#: 32-pixel step, so a car 64-100 pixels wide in any other lane falls between
#: the 48- and 112-pixel scales: the white car of test3 (88x53 at x 872) is
#: missed.  Here it spans the whole width with the 0.75 overlap of the large
#: scales, over the band where a 64-pixel car can stand (y 396-500: on a flat
#: road its bottom edge lies a fixed distance below the horizon; lower down,
#: cars are larger and the 112- and 128-pixel scales cover them).  Cost: 159
#: more windows (1020) and 0.35 ms per frame; see the README's quality section.
DEFAULT_SCALES = (
    PUBLISHED_SCALES[0],
    PUBLISHED_SCALES[1],
    ScaleConfig(64, 0.75, (0, 1280), (396, 500)),
    PUBLISHED_SCALES[3],
    PUBLISHED_SCALES[4],
)


@dataclass(frozen=True)
class SearchConfig:
    """Where and how windows are searched and which count as hits.

    Parameters
    ----------
    scales : tuple of ScaleConfig
    reference_size : tuple of int
        ``(width, height)`` the scale coordinates refer to.
    decision_threshold : float
        A window is a hit when its SVM margin exceeds this.
    """

    scales: tuple = DEFAULT_SCALES
    reference_size: tuple = (1280, 720)
    decision_threshold: float = -0.25

    def __post_init__(self):
        object.__setattr__(self, "scales", tuple(self.scales))
        object.__setattr__(self, "reference_size", tuple(self.reference_size))
        if not self.scales:
            raise ConfigError("search.scales must list at least one scale")
        size = self.reference_size
        if len(size) != 2 or not all(isinstance(v, int) and v > 0 for v in size):
            raise ConfigError(f"search.reference_size must be [width, height], got {list(size)!r}")
        _number("search.decision_threshold", self.decision_threshold)


@dataclass(frozen=True)
class HeatConfig:
    """How hit windows are merged.

    Parameters
    ----------
    threshold : float
        Pixels whose heat exceeds this belong to a vehicle.
    weighting : {'count', 'area', 'margin'}
        Heat each hit adds: 1; ``(64 / window side) ** 2`` (small windows count
        more, as one published pipeline does); or its SVM margin above the
        decision threshold.
    connectivity : {4, 8}
        Pixel connectivity of the labelling.
    peak_fraction : float
        Box refinement: a component's box is the bounding box of its pixels
        whose heat reaches this fraction of the component's peak (0 keeps the
        whole component).  Square windows overhang wide cars; the overlap of
        many hits, where the heat peaks, follows the car more closely.
    split : bool
        Split a blob whose heat has two or more peaks (two cars side by
        side) by raising its threshold until it falls apart, but only into
        parts that are each at least ``split_min_size`` wide and tall.
    split_min_size : float
        Smallest part that counts as a car, in reference-frame pixels.
    """

    threshold: float = 3.0
    weighting: str = "margin"
    connectivity: int = 8
    peak_fraction: float = 0.3
    split: bool = True
    split_min_size: float = 48.0

    def __post_init__(self):
        _number("heat.threshold", self.threshold)
        _number("heat.peak_fraction", self.peak_fraction)
        if not 0 <= self.peak_fraction <= 1:
            raise ConfigError(f"heat.peak_fraction must be in [0, 1], got {self.peak_fraction!r}")
        if not isinstance(self.split, bool):
            raise ConfigError(f"heat.split must be true or false, got {self.split!r}")
        _number("heat.split_min_size", self.split_min_size)
        if self.weighting not in ("count", "area", "margin"):
            raise ConfigError(f"heat.weighting must be 'count', 'area' or 'margin', "
                              f"got {self.weighting!r}")
        if self.connectivity not in (4, 8):
            raise ConfigError(f"heat.connectivity must be 4 or 8, got {self.connectivity!r}")


@dataclass(frozen=True)
class BoxConfig:
    """Sanity filters on the final boxes (reference-frame pixels).

    Parameters
    ----------
    min_size : float
        Boxes narrower or shorter than this are dropped.
    min_aspect, max_aspect : float
        Allowed width / height ratio.
    horizon_y : float
        Boxes lying entirely above this line (bottom edge <= it) are dropped.
    width_scale, height_scale : float
        Box shape correction, applied about the box centre before the
        filters: square windows make heat blobs narrower and taller than
        the (wide) cars they cover.  Fitted by ``fastdet tune``.
    center_dy : float
        Vertical shift of the box centre, as a fraction of the box height.
    """

    min_size: float = 24.0
    min_aspect: float = 0.5
    max_aspect: float = 3.0
    horizon_y: float = 380.0
    width_scale: float = 1.2
    height_scale: float = 0.8
    center_dy: float = 0.05

    def __post_init__(self):
        for name in ("min_size", "min_aspect", "max_aspect", "horizon_y", "width_scale",
                     "height_scale", "center_dy"):
            _number(f"boxes.{name}", getattr(self, name))
        if not 0 < self.min_aspect <= self.max_aspect:
            raise ConfigError("boxes.min_aspect must be > 0 and <= boxes.max_aspect")
        for name in ("width_scale", "height_scale"):
            if not 0.25 <= getattr(self, name) <= 4:
                raise ConfigError(f"boxes.{name} must be in [0.25, 4], got {getattr(self, name)!r}")


@dataclass(frozen=True)
class DetectorConfig:
    """Everything a :class:`fastdet.Detector` needs besides its model."""

    search: SearchConfig = field(default_factory=SearchConfig)
    heat: HeatConfig = field(default_factory=HeatConfig)
    boxes: BoxConfig = field(default_factory=BoxConfig)

    @classmethod
    def from_dict(cls, data, extra_sections=()):
        """Build from nested dicts (parsed TOML), defaults for what is missing.

        Parameters
        ----------
        data : dict
        extra_sections : iterable of str
            Top-level sections other components own (ignored here, not rejected).
        """
        sections = {"search": SearchConfig, "heat": HeatConfig, "boxes": BoxConfig}
        unknown = sorted(set(data) - set(sections) - set(extra_sections))
        if unknown:
            raise ConfigError(f"unknown config section(s): {', '.join(unknown)}")
        built = {}
        for name, section_cls in sections.items():
            values = data.get(name, {})
            if not isinstance(values, dict):
                raise ConfigError(f"[{name}] must be a table, got {values!r}")
            values = dict(values)
            if name == "search" and "scales" in values:
                if not isinstance(values["scales"], list):
                    raise ConfigError("search.scales must be a list of [[search.scales]] tables")
                values["scales"] = tuple(_build(ScaleConfig, scale, "search.scales")
                                         for scale in values["scales"])
            built[name] = _build(section_cls, values, name)
        return cls(**built)


def _build(section_cls, values, section):
    if not isinstance(values, dict):
        raise ConfigError(f"[{section}] must be a table")
    known = {f.name for f in dataclasses.fields(section_cls)}
    unknown = sorted(set(values) - known)
    if unknown:
        raise ConfigError(f"unknown key(s) in [{section}]: {', '.join(unknown)}")
    try:
        return section_cls(**values)
    except ConfigError:
        raise
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"invalid [{section}]: {exc}") from None


def read_toml(path):
    """Parse a TOML file into a dict with a one-line error on failure."""
    path = Path(path)
    if path.is_dir():
        raise ConfigError(f"{path} is a folder, not a config file")
    if not path.is_file():
        raise ConfigError(f"config file not found: {path}")
    try:
        with open(path, "rb") as handle:
            return tomllib.load(handle)
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path} is not valid TOML: {exc}") from None


def load_config(path=None, extra_sections=("track",)):
    """The detector configuration: defaults, overridden by a TOML file if given."""
    if path is None:
        return DetectorConfig()
    try:
        return DetectorConfig.from_dict(read_toml(path), extra_sections)
    except ConfigError as exc:
        if str(path) in str(exc):
            raise
        raise ConfigError(f"{path}: {exc}") from None
