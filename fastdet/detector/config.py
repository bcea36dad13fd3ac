"""Detector configuration: dataclasses with built-in defaults, overridable from TOML.

A TOML file only lists what it changes::

    [search]
    decision_threshold = 0.3
    horizon = 0.55             # the horizon row, as a fraction of the frame height ("auto":
                               # estimated from the lane lines, fastdet.detector.horizon)

    [[search.windows]]         # giving windows replaces the whole list
    size = 0.08                # window side, as a fraction of the frame height
    overlap = 0.75

    [heat]
    threshold = 2

    [boxes]
    min_size = 24

Unknown sections or keys are rejected with their name.

The default search is laid out relative to the frame and its horizon, so the
same settings serve any camera and frame size: on a flat road a vehicle's
width is proportional to how far below the horizon it stands, whatever the
lens, so each window size is searched only in the band of rows where a
vehicle of its size can stand (:class:`WindowConfig`; the plan is
:func:`fastdet.detector.plan.plan_scales`), and the small windows, which
only fit far vehicles, only near the middle of the frame, where the road
vanishes.  An explicit list of ``[[search.scales]]`` (window, overlap and
region in pixels of a ``search.reference_size`` frame, 1280x720, scaled
proportionally for other frame sizes: the form configurations had before)
replaces the windows; ``fastdet/data/published_search.toml`` is one.

Other pixel settings (``[boxes] min_size``, ``horizon_y``, ``[heat]
split_min_size``, ``[track] search_radius``) are given for a
``search.reference_size`` frame and scaled with the frame.

The default thresholds and box-shape correction are the ones ``fastdet tune``
chose for the bundled model on the development frames of the annotated
videos (``tools/build_default_model.py``); the test images play no part in
them.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib

from ..errors import ConfigError
from .plain import plain_numbers
from .refine import N_FEATURES


def _is_number(value):
    """A finite int or float (bools, which are ints, are not numbers here)."""
    return (isinstance(value, (int, float)) and not isinstance(value, bool)
            and math.isfinite(value))


#: Largest size of any number of the detector's settings: pixels, thresholds
#: and coefficients are all far smaller, and a larger one (1e19, 1e308) passed
#: the checks and then overflowed in the kernels' integer and float32 arguments.
MAX_SETTING = 1e9


def _tuple(name, value):
    """``value`` as a tuple; ``None`` or a number (not a list) is a
    :class:`ConfigError` naming the setting, not ``tuple()``'s TypeError."""
    try:
        return tuple(value)
    except TypeError:
        raise ConfigError(f"{name} must be a list, got {value!r}") from None


def _number(name, value, kind="a finite number"):
    if not _is_number(value):
        raise ConfigError(f"{name} must be {kind}, got {value!r}")
    if abs(value) > MAX_SETTING:
        raise ConfigError(f"{name} must be at most {MAX_SETTING:g} in size, got {value!r}")


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
        plain_numbers(self)
        object.__setattr__(self, "x", _tuple("search.scales.x", self.x))
        object.__setattr__(self, "y", _tuple("search.scales.y", self.y))
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


@dataclass(frozen=True)
class WindowConfig:
    """One window size of the frame-relative search.

    Parameters
    ----------
    size : float
        Window side as a fraction of the frame height.
    overlap : float
        Fraction in [0, 1) by which neighbouring windows overlap (both
        axes); the step is rounded to whole HOG cells.

    Notes
    -----
    Where the windows of a size lie follows from :class:`SearchConfig`'s
    ``horizon``, ``band``, ``margin`` and ``reach``.
    """

    size: float
    overlap: float

    def __post_init__(self):
        plain_numbers(self)
        _number("search.windows.size", self.size)
        if not 0 < self.size <= 1:
            raise ConfigError(f"search.windows.size must be in (0, 1] (a fraction of the frame "
                              f"height), got {self.size!r}")
        # _number refuses bools: ``overlap = false`` was taken as 0.
        _number("search.windows.overlap", self.overlap)
        if not 0 <= self.overlap < 1:
            raise ConfigError(f"search.windows.overlap must be in [0, 1), got {self.overlap!r}")


#: The five scales of the published pipeline this project starts from
#: (``fastdet/data/published_search.toml`` restores them).
PUBLISHED_SCALES = (
    ScaleConfig(32, 0.0, (320, 960), (396, 460)),
    ScaleConfig(48, 0.5, (0, 1280), (360, 540)),
    ScaleConfig(64, 0.5, (426, 853), (396, 648)),
    ScaleConfig(112, 0.75, (0, 1280), (360, 630)),
    ScaleConfig(128, 0.75, (0, 1280), (360, 630)),
)

#: The pixel scales fastdet searched by default before the frame-relative
#: search: the published ones with the 64-pixel scale over the whole width
#: at overlap 0.75 and y 396-500 (``fastdet/data/previous_search.toml``).
PREVIOUS_SCALES = (
    PUBLISHED_SCALES[0],
    PUBLISHED_SCALES[1],
    ScaleConfig(64, 0.75, (0, 1280), (396, 500)),
    PUBLISHED_SCALES[3],
    PUBLISHED_SCALES[4],
)

#: The horizon of both cameras the defaults were chosen on (a fraction of
#: the frame height); ``[boxes] horizon_y`` goes with it.
DEFAULT_HORIZON = 0.58
#: ``[search] horizon = "auto"``: estimated from the frames.
AUTO = "auto"
#: ``[boxes] horizon_y`` at the default horizon (reference rows); it moves with the horizon.
DEFAULT_HORIZON_Y = 380.0

#: The default window sizes: 32, 48, 64, 96 and 128 pixels on a 720-row
#: frame, as fractions of the frame height (0.0444 ... 0.1778).  At 720
#: rows the 64-pixel windows are read from the frame without resizing.
DEFAULT_WINDOWS = (
    WindowConfig(32 / 720, 0.5),
    WindowConfig(48 / 720, 0.5),
    WindowConfig(64 / 720, 0.75),
    WindowConfig(96 / 720, 0.75),
    WindowConfig(128 / 720, 0.75),
)


@dataclass(frozen=True)
class SearchConfig:
    """Where and how windows are searched and which count as hits.

    The default layout is relative to the frame: each of ``windows`` is
    searched in a band of rows around the ``horizon`` (where a vehicle of
    the window's size stands on a flat road) and within ``reach`` window
    sides of the frame's middle column.  A non-empty ``scales`` lays the
    search out in pixels instead (the windows are then not used).

    Parameters
    ----------
    windows : tuple of WindowConfig
        Window sizes of the frame-relative search.
    horizon : float or "auto"
        Row of the horizon (the vanishing point of the road) as a fraction
        of the frame height from the top.  ``"auto"``: estimated from the
        camera's frames, where its lane lines meet
        (:mod:`fastdet.detector.horizon`), before any is searched: ``fastdet
        run``, ``eval`` and ``batch`` from each video's first frames,
        ``detect`` and ``eval`` on images from all the images given.  A
        :class:`~fastdet.Detector` searches numeric horizons only: in code,
        call its ``resolve_horizon(frames)`` first.
    band : tuple of float
        ``(low, high)``: a window's top edge lies between ``horizon + low *
        side`` and ``horizon + high * side``.  A vehicle's width is about
        twice its bottom edge's distance below the horizon, whatever the
        lens, so a window framing it has its top edge 0.6 to 0.2 sides above
        the horizon (trucks and near, oblique cars at the high end).
    margin : float
        Rows searched beyond every band, above and below, as a fraction of
        the frame height: the camera pitches and the road is not flat.
    reach : float
        Window centres lie at most this many window sides left or right of
        the frame's middle column: a vehicle ``n`` of its own widths beside
        the road's vanishing point is ``n`` vehicle widths to the side, so
        10 reaches five lanes either way.  Large windows reach the frame
        edges anyway.
    scales : tuple of ScaleConfig
        An explicit pixel layout (empty: the frame-relative one).
    reference_size : tuple of int
        ``(width, height)`` the pixel settings (``scales``, the box filters,
        ...) refer to.
    decision_threshold : float
        A window is a hit when its SVM margin exceeds this.
    """

    windows: tuple = DEFAULT_WINDOWS
    horizon: float | str = DEFAULT_HORIZON
    band: tuple = (-0.6, -0.2)
    margin: float = 0.02
    reach: float = 10.0
    scales: tuple = ()
    reference_size: tuple = (1280, 720)
    decision_threshold: float = -0.5

    @property
    def auto_horizon(self):
        """Whether the horizon is to be estimated from the frames (``"auto"``)."""
        return self.horizon == AUTO

    def __post_init__(self):
        plain_numbers(self)
        for name in ("windows", "band", "scales", "reference_size"):
            object.__setattr__(self, name, _tuple(f"search.{name}", getattr(self, name)))
        if not self.scales and not self.windows:
            raise ConfigError("search.windows (or search.scales) must list at least one size")
        # Built in code, a window or scale may be anything: a dict passed here
        # and failed on an attribute in the middle of the first detection.
        for name, item_cls in (("windows", WindowConfig), ("scales", ScaleConfig)):
            for item in getattr(self, name):
                if not isinstance(item, item_cls):
                    raise ConfigError(f"search.{name} must hold {item_cls.__name__}s, "
                                      f"got {type(item).__name__}")
        size = self.reference_size
        if len(size) != 2 or not all(isinstance(v, int) and not isinstance(v, bool)
                                     and 0 < v <= MAX_SETTING for v in size):
            raise ConfigError(f"search.reference_size must be [width, height], got {list(size)!r}")
        _number("search.decision_threshold", self.decision_threshold)
        if self.horizon != AUTO:
            _number("search.horizon", self.horizon, f'a number or "{AUTO}"')
            if not 0 < self.horizon < 1:
                raise ConfigError(f"search.horizon must be in (0, 1) (a fraction of the frame "
                                  f"height) or \"{AUTO}\", got {self.horizon!r}")
        if (len(self.band) != 2 or not all(_is_number(v) for v in self.band)
                or not self.band[0] <= self.band[1]):
            raise ConfigError(f"search.band must be [low, high] with low <= high, "
                              f"got {list(self.band)!r}")
        _number("search.margin", self.margin)
        if self.margin < 0:
            raise ConfigError(f"search.margin must be >= 0, got {self.margin!r}")
        # ``reach = inf`` passed as "> 0".
        _number("search.reach", self.reach, "a finite number > 0")
        if not self.reach > 0:
            raise ConfigError(f"search.reach must be a number > 0, got {self.reach!r}")


#: What a hit adds to the heat (see :class:`HeatConfig`).
HEAT_WEIGHTINGS = ("count", "area", "margin", "margin_area")


@dataclass(frozen=True)
class HeatConfig:
    """How hit windows are merged.

    Parameters
    ----------
    threshold : float
        Pixels whose heat exceeds this belong to a vehicle.
    weighting : {'count', 'area', 'margin', 'margin_area'}
        Heat each hit adds: 1; ``(64 / window side) ** 2`` with the side in
        reference-frame pixels (small windows count more, as one published
        pipeline does); its SVM margin above the decision threshold; or the
        product of the last two (a small, far car is framed by few windows
        of one size, a near one by many of several).
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
    peak_fraction: float = 0.5
    split: bool = True
    split_min_size: float = 32.0

    def __post_init__(self):
        plain_numbers(self)
        _number("heat.threshold", self.threshold)
        _number("heat.peak_fraction", self.peak_fraction)
        if not 0 <= self.peak_fraction <= 1:
            raise ConfigError(f"heat.peak_fraction must be in [0, 1], got {self.peak_fraction!r}")
        if not isinstance(self.split, bool):
            raise ConfigError(f"heat.split must be true or false, got {self.split!r}")
        _number("heat.split_min_size", self.split_min_size)
        if self.weighting not in HEAT_WEIGHTINGS:
            raise ConfigError(f"heat.weighting must be one of {', '.join(HEAT_WEIGHTINGS)}, "
                              f"got {self.weighting!r}")
        if self.connectivity not in (4, 8):
            raise ConfigError(f"heat.connectivity must be 4 or 8, got {self.connectivity!r}")


#: The box refinement ``fastdet tune`` fitted for the bundled model on the
#: development frames (``tools/build_default_model.py``): rows x1, y1, x2,
#: y2 over the features of :func:`fastdet.detector.refine.heat_features`.
DEFAULT_REFINE = (
    (0.27312, 0.08669, 0.04828, 0.06029, -0.03011, 0.30224, 0.02330, -0.04854, 0.01643,
     0.13859, 0.03097, -0.02454, -0.03778, 0.28056, -0.48630),
    (0.02455, 0.01545, 0.02511, 0.03887, 0.02195, 0.04369, 0.04678, 0.01192, -0.00095, 0.03450,
     0.02600, -0.00104, -0.01181, 0.12592, -0.21905),
    (0.90507, -0.07789, -0.04873, 0.15153, 0.15427, 0.02751, -0.08195, -0.11701, 0.23935,
     0.04428, 0.07219, 0.03708, 0.04564, 0.33221, 0.29332),
    (0.47952, -0.01413, -0.03140, 0.00837, 0.12941, 0.01076, -0.01880, -0.07573, 0.17063,
     0.00259, 0.05830, 0.00086, 0.03658, 0.04495, 0.04172),
)


@dataclass(frozen=True)
class BoxConfig:
    """Sanity filters on the final boxes (reference-frame pixels).

    Parameters
    ----------
    min_size : float
        Boxes narrower or shorter than this are dropped.
    min_aspect, max_aspect : float
        Allowed width / height ratio.
    horizon_y : float or None
        Boxes lying entirely above this line (bottom edge <= it) are dropped.
        ``None``: :data:`DEFAULT_HORIZON_Y` moved as far as the search
        horizon lies from :data:`DEFAULT_HORIZON` (``"auto"`` included, once
        resolved), see :meth:`DetectorConfig.horizon_line`.
    width_scale, height_scale : float
        Box shape correction, applied about the box centre before the
        filters: square windows make heat blobs narrower and taller than
        the (wide) cars they cover.  Fitted by ``fastdet tune``.
    center_dy : float
        Vertical shift of the box centre, as a fraction of the box height.
    refine : tuple of tuple of float
        Box refinement (:mod:`fastdet.detector.refine`): four rows (x1, y1,
        x2, y2) of weights over the box's heat features; when given they
        place the edges instead of the shape correction.  Fitted by
        ``fastdet tune``; empty: shape correction only.
    snap_sides : float
        After the refinement, each refined box's left and right edges move
        to the strongest vertical image edge within this fraction of the
        box width (:func:`fastdet.kernels.refine.snap_box_sides`); 0 turns
        it off.
        0.1 was chosen on the tuning frames of both videos (README,
        "Detection quality").
    """

    min_size: float = 24.0
    min_aspect: float = 0.5
    max_aspect: float = 3.0
    horizon_y: float | None = None
    width_scale: float = 1.5
    height_scale: float = 1.0
    center_dy: float = 0.05
    refine: tuple = DEFAULT_REFINE
    snap_sides: float = 0.1

    def __post_init__(self):
        plain_numbers(self)
        object.__setattr__(self, "refine", tuple(_tuple("boxes.refine", row)
                                                 for row in _tuple("boxes.refine", self.refine)))
        if self.refine and (len(self.refine) != 4 or any(
                len(row) != N_FEATURES or not all(_is_number(v) and abs(v) <= MAX_SETTING
                                                  for v in row)
                for row in self.refine)):
            raise ConfigError(f"boxes.refine must be 4 rows of {N_FEATURES} numbers "
                              f"of at most {MAX_SETTING:g} in size (or empty)")
        for name in ("min_size", "min_aspect", "max_aspect", "width_scale", "height_scale",
                     "center_dy"):
            _number(f"boxes.{name}", getattr(self, name))
        if self.horizon_y is not None:
            _number("boxes.horizon_y", self.horizon_y)
        if not 0 < self.min_aspect <= self.max_aspect:
            raise ConfigError("boxes.min_aspect must be > 0 and <= boxes.max_aspect")
        _number("boxes.snap_sides", self.snap_sides)
        if not 0 <= self.snap_sides < 0.5:
            raise ConfigError(f"boxes.snap_sides must be in [0, 0.5), got {self.snap_sides!r}")
        for name in ("width_scale", "height_scale"):
            if not 0.25 <= getattr(self, name) <= 4:
                raise ConfigError(f"boxes.{name} must be in [0.25, 4], got {getattr(self, name)!r}")


@dataclass(frozen=True)
class DetectorConfig:
    """Everything a :class:`fastdet.Detector` needs besides its model."""

    search: SearchConfig = field(default_factory=SearchConfig)
    heat: HeatConfig = field(default_factory=HeatConfig)
    boxes: BoxConfig = field(default_factory=BoxConfig)

    def __post_init__(self):
        plain_numbers(self)
        # A section of another type (a dict, None) was taken and failed on an
        # attribute in the middle of the first detection.
        for name, section_cls in (("search", SearchConfig), ("heat", HeatConfig),
                                  ("boxes", BoxConfig)):
            section = getattr(self, name)
            if not isinstance(section, section_cls):
                raise ConfigError(f"{name} must be a {section_cls.__name__}, got "
                                  f"{type(section).__name__}"
                                  + (" (DetectorConfig.from_dict reads nested dicts)"
                                     if isinstance(section, dict) else ""))

    def with_horizon(self, fraction):
        """This configuration searched about the horizon row ``fraction`` (``[boxes]
        horizon_y``, unless set, follows it: :meth:`horizon_line`)."""
        if isinstance(fraction, bool) or not isinstance(fraction, numbers.Real):
            # float() read "0.5" and failed on "auto" with its own message.
            raise ConfigError(f"search.horizon must be a number here, got {fraction!r}")
        return dataclasses.replace(self, search=dataclasses.replace(self.search,
                                                                    horizon=float(fraction)))

    def horizon_line(self):
        """``[boxes] horizon_y`` in reference rows: as set, or :data:`DEFAULT_HORIZON_Y`
        moved with the search horizon (not moved while that is an unresolved ``"auto"``)."""
        if self.boxes.horizon_y is not None:
            return float(self.boxes.horizon_y)
        horizon = DEFAULT_HORIZON if self.search.auto_horizon else self.search.horizon
        return DEFAULT_HORIZON_Y + (horizon - DEFAULT_HORIZON) * self.search.reference_size[1]

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
        if not isinstance(data, dict):
            raise ConfigError(f"a configuration must be a table (a dict), got "
                              f"{type(data).__name__}")
        unknown = sorted(map(str, set(data) - set(sections) - set(extra_sections)))
        if unknown:
            raise ConfigError(f"unknown config section(s): {', '.join(unknown)}")
        built = {}
        for name, section_cls in sections.items():
            values = _table(data.get(name, {}), name)
            if name == "search":
                values = _search_values(values)
            built[name] = _build(section_cls, values, name)
        return cls(**built)


def _search_values(values):
    """``[search]`` with its lists of tables built; listing scales drops the windows."""
    if "scales" in values and "windows" in values:
        raise ConfigError("search.scales (pixels) and search.windows (fractions of the frame) "
                          "are two layouts of the search: list one of them")
    for key, item_cls in (("scales", ScaleConfig), ("windows", WindowConfig)):
        if key in values:
            if not isinstance(values[key], list):
                raise ConfigError(f"search.{key} must be a list of tables ([[search.{key}]])")
            values[key] = tuple(_build(item_cls, _table(item, f"search.{key}"), f"search.{key}")
                                for item in values[key])
    if "scales" in values:
        values["windows"] = ()
    return values


def _table(values, section):
    if not isinstance(values, dict):
        raise ConfigError(f"[{section}] must be a table, got {values!r}")
    return dict(values)


def _build(section_cls, values, section):
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


def with_search_horizon(config, horizon):
    """``config`` with ``[search] horizon`` set to ``horizon`` (a fraction or
    ``"auto"``, validated), or as it is for ``None`` (``--horizon`` not given)."""
    if horizon is None:
        return config
    return dataclasses.replace(config, search=dataclasses.replace(config.search,
                                                                  horizon=horizon))


def read_toml(path):
    """Parse a TOML file into a dict with a one-line error on failure.

    Raises
    ------
    ConfigError
        When the file is missing, a folder, not a regular file, or not TOML.
    TypeError
        When ``path`` is not a path.
    """
    if not isinstance(path, (str, os.PathLike)):
        # Path() said "expected str, bytes or os.PathLike", and bytes failed too.
        raise TypeError(f"a config file must be given by its path, got {type(path).__name__}")
    if not os.fspath(path):
        raise ConfigError("the config file's path is empty")   # Path("") is ".", a folder
    path = Path(path)
    if path.is_dir():
        raise ConfigError(f"{path} is a folder, not a config file")
    if path.exists() and not path.is_file():
        raise ConfigError(f"{path} is not a regular file (a config is read from a file)")
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
