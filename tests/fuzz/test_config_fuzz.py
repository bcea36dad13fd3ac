"""Fuzzing the config loader with random TOML documents and random bytes.

The promise: ``load_config`` and ``load_track_config`` either return a
configuration every frame size can be planned with, or raise
:class:`fastdet.ConfigError`; nothing else escapes.
"""

from __future__ import annotations

import datetime
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fastdet import ConfigError, load_config, load_track_config
from fastdet.detector.features import FeatureOptions
from fastdet.detector.plan import plan_scales

#: The keys the loaders know, so that documents reach the value checks.
KNOWN = {
    "search": ["decision_threshold", "reference_size", "scales"],
    "scales": ["window", "overlap", "x", "y"],
    "heat": ["threshold", "weighting", "connectivity", "peak_fraction", "split",
             "split_min_size"],
    "boxes": ["min_size", "min_aspect", "max_aspect", "horizon_y", "width_scale",
              "height_scale", "center_dy"],
    "track": ["every", "heat_smoothing", "heat_alpha", "heat_frames", "box_frames", "tracking",
              "match_iou", "max_missed", "saturation_threshold", "min_patch_overlap"],
}

FRAME_SIZES = [(1280, 720), (1, 1), (7, 3000), (4000, 2)]


def toml_key(text):
    return text if text.replace("_", "").isalnum() and text.isascii() else f'"{text}"'


def toml_value(value):
    """A TOML literal of ``value`` (strings quoted, floats' nan and inf spelled as TOML does)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (datetime.date, datetime.time)):
        return value.isoformat()
    if isinstance(value, list):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{toml_key(k)} = {toml_value(v)}" for k, v in value.items()) + "}"
    raise AssertionError(type(value))


scalars = st.one_of(
    st.booleans(), st.integers(-2 ** 63, 2 ** 63 - 1), st.floats(),
    st.integers(-3, 2000), st.floats(-2, 2000), st.text(max_size=8),
    st.sampled_from(["count", "area", "margin", "none", "exponential", "fir", "all"]),
    st.dates(), st.times(),
)
values = st.recursive(scalars, lambda inner: st.one_of(
    st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=6), inner, max_size=3)),
    max_leaves=8)


numbers = st.one_of(st.integers(-3, 2000), st.floats(-2, 2000), st.floats(),
                    st.integers(-2 ** 63, 2 ** 63 - 1))
#: Values close to what each key wants (numbers, pairs of numbers) or anything at all.
near_valid = st.one_of(numbers, st.lists(numbers, min_size=2, max_size=2), values)


def key_values(keys):
    """A table: mostly known keys with near-valid values, sometimes unknown ones."""
    return st.dictionaries(st.one_of(st.sampled_from(keys), st.text(min_size=1, max_size=8)),
                           near_valid, max_size=6)


@st.composite
def documents(draw):
    """A random config as a dict: known sections with near-valid tables, or anything."""
    document = {}
    for section in draw(st.lists(st.sampled_from(["search", "heat", "boxes", "track", "other"]),
                                 max_size=4, unique=True)):
        table = draw(st.one_of(key_values(KNOWN.get(section, ["anything"])), values))
        if section == "search" and isinstance(table, dict) and draw(st.booleans()):
            table["scales"] = draw(st.one_of(
                st.lists(key_values(KNOWN["scales"]), max_size=3), values))
        document[section] = table
    return document


def to_toml(document):
    """TOML text of a document: plain keys first, then tables and arrays of tables."""
    def emit(table, prefix, lines):
        nested = []
        for key, value in table.items():
            if isinstance(value, dict):
                nested.append((key, value, False))
            elif isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
                nested.append((key, value, True))
            else:
                lines.append(f"{toml_key(key)} = {toml_value(value)}")
        for key, value, is_array in nested:
            name = f"{prefix}{toml_key(key)}"
            for item in (value if is_array else [value]):
                lines.append(f"[[{name}]]" if is_array else f"[{name}]")
                emit(item, name + ".", lines)
    lines = []
    emit(document, "", lines)
    return "\n".join(lines) + "\n"


def check_loads(path):
    """Load both configs; a config that loads must plan every frame size."""
    try:
        config = load_config(path)
    except ConfigError:
        config = None
    if config is not None:
        for size in FRAME_SIZES:
            plan_scales(config, FeatureOptions(), size)
    try:
        load_track_config(path)
    except ConfigError:
        pass


@given(document=documents())
def test_random_documents(tmp_path_factory, document):
    path = tmp_path_factory.mktemp("config") / "config.toml"
    path.write_text(to_toml(document), encoding="utf-8")
    check_loads(path)


@given(data=st.binary(max_size=200))
def test_random_bytes(tmp_path_factory, data):
    path = tmp_path_factory.mktemp("config") / "config.toml"
    path.write_bytes(data)
    check_loads(path)


@pytest.mark.parametrize("text", [
    "[search]\nscales = 5\n",              # scales must be a list of tables
    "search = 3\n",                        # a section must be a table
    "[[search.scales]]\nwindow = 64\noverlap = 0.5\nx = [0, inf]\ny = [0, 720]\n",
    "[[search.scales]]\nwindow = inf\noverlap = 0.5\nx = [0, 10]\ny = [0, 720]\n",
    "[[search.scales]]\nwindow = 64\noverlap = 0.5\nx = [0, 10]\ny = [true, 720]\n",
])
def test_found_cases_are_config_errors(tmp_path, text):
    path = tmp_path / "config.toml"
    path.write_text(text)
    with pytest.raises(ConfigError):
        load_config(path)
