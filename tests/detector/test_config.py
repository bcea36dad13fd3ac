"""Detector configuration: defaults, TOML overrides and one-line errors."""

from pathlib import Path

import numpy as np
import pytest

import fastdet
from fastdet.detector.config import (
    DEFAULT_WINDOWS,
    PREVIOUS_SCALES,
    PUBLISHED_SCALES,
    BoxConfig,
    DetectorConfig,
    ScaleConfig,
    SearchConfig,
    WindowConfig,
    load_config,
)
from fastdet.errors import ConfigError


def write(tmp_path, text):
    path = tmp_path / "config.toml"
    path.write_text(text)
    return path


def test_defaults_are_frame_relative_windows():
    config = load_config(None)
    assert config.search.scales == ()
    assert config.search.windows == DEFAULT_WINDOWS
    # 32 to 128 pixels on a 720-row frame, as the published scales.
    sides = [round(w.size * 720) for w in DEFAULT_WINDOWS]
    assert sides[0] == 32 and sides[-1] == 128 and sides == sorted(sides)
    assert 0 < config.search.horizon < 1


@pytest.mark.parametrize("name, scales", [("published_search.toml", PUBLISHED_SCALES),
                                          ("previous_search.toml", PREVIOUS_SCALES)])
def test_shipped_pixel_searches_load_as_before(name, scales):
    config = load_config(Path(fastdet.__file__).parent / "data" / name)
    assert config.search.scales == scales
    assert config.search.windows == ()


def test_shipped_published_search_restores_the_published_scales():
    path = Path(fastdet.__file__).parent / "data" / "published_search.toml"
    config = load_config(path)
    assert config.search.scales == PUBLISHED_SCALES
    assert config.heat == DetectorConfig().heat


def test_override_keeps_unlisted_defaults(tmp_path):
    config = load_config(write(tmp_path, "[heat]\nthreshold = 3\n[search]\ndecision_threshold = -0.5\n"))
    assert config.heat.threshold == 3
    assert config.search.decision_threshold == -0.5
    assert config.heat.connectivity == DetectorConfig().heat.connectivity
    assert config.search.windows == DEFAULT_WINDOWS


def test_windows_replace_the_list(tmp_path):
    config = load_config(write(tmp_path, "[search]\nhorizon = 0.5\n"
                                         "[[search.windows]]\nsize = 0.1\noverlap = 0.5\n"))
    assert config.search.windows == (WindowConfig(0.1, 0.5),)
    assert config.search.horizon == 0.5


def test_scales_replace_the_list(tmp_path):
    config = load_config(write(tmp_path, "[[search.scales]]\nwindow = 80\noverlap = 0.5\n"
                                         "x = [0, 1280]\ny = [380, 600]\n"))
    assert len(config.search.scales) == 1
    assert config.search.scales[0].window == 80
    assert config.search.windows == ()  # an explicit pixel layout replaces the windows


@pytest.mark.parametrize("text, words", [
    ("[heat]\nthreshhold = 2\n", "threshhold"),
    ("[nonsense]\na = 1\n", "nonsense"),
    ("[heat]\nconnectivity = 6\n", "connectivity"),
    ("[heat]\nweighting = 'loud'\n", "weighting"),
    ("[search]\ndecision_threshold = 'high'\n", "decision_threshold"),
    ("[[search.scales]]\nwindow = 64\noverlap = 1.5\nx = [0, 10]\ny = [0, 10]\n", "overlap"),
    ("[[search.scales]]\nwindow = 64\noverlap = 0.5\nx = [100, 10]\ny = [0, 10]\n", "x"),
    ("[[search.scales]]\nwindow = 64\noverlap = 0.5\nx = [0, 100]\n", "y"),
    ("[boxes]\nmin_aspect = 4.0\nmax_aspect = 3.0\n", "min_aspect"),
    ("[boxes]\nsnap_sides = 0.5\n", "snap_sides must be in [0, 0.5)"),
    ("[boxes]\nsnap_sides = -0.1\n", "snap_sides"),
    ("[boxes]\nsnap_sides = 'yes'\n", "snap_sides"),
    ("[search\n", "not valid TOML"),
    ("[search]\nhorizon = 1.5\n", "horizon"),
    ("[search]\nband = [0.2, -0.6]\n", "band"),
    ("[search]\nmargin = -0.1\n", "margin"),
    ("[search]\nreach = 0\n", "reach"),
    ("[search]\nreach = inf\n", "search.reach must be a finite number"),
    ("[[search.windows]]\nsize = 0.1\noverlap = false\n", "search.windows.overlap must be"),
    ("[[search.windows]]\nsize = 0.1\noverlap = nan\n", "search.windows.overlap must be"),
    ("[[search.windows]]\nsize = 2.0\noverlap = 0.5\n", "size"),
    ("[[search.windows]]\nsize = 0.1\n", "overlap"),
    ("[search]\nwindows = 3\n", "list of tables"),
    # Finite numbers past any sensible size overflowed the kernels' arguments
    # (1e19 an int64, 1e39 a float32) or made infinite boxes:
    ("[search]\nreference_size = [true, true]\n", "reference_size"),
    ("[search]\nband = [true, true]\n", "band"),
    ("[heat]\nsplit_min_size = 1e19\n", "heat.split_min_size must be at most 1e+09 in size"),
    ("[search]\ndecision_threshold = -1e39\n", "decision_threshold must be at most 1e+09"),
    ("[boxes]\nrefine = [" + ", ".join(["[" + ", ".join(["1e308"] * 15) + "]"] * 4) + "]\n",
     "boxes.refine must be 4 rows of 15 numbers of at most 1e+09 in size"),
    ("[[search.windows]]\nsize = 0.1\noverlap = 0.5\n[[search.scales]]\nwindow = 64\n"
     "overlap = 0.5\nx = [0, 10]\ny = [0, 10]\n", "list one of them"),
])
def test_invalid_configs_name_the_problem(tmp_path, text, words):
    with pytest.raises(ConfigError) as info:
        load_config(write(tmp_path, text))
    message = str(info.value)
    assert words in message
    assert "\n" not in message


def test_missing_config_file(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "absent.toml")


def test_track_section_is_left_to_the_tracker(tmp_path):
    config = load_config(write(tmp_path, "[track]\nevery = 5\n"))
    assert config == DetectorConfig()


def test_the_readmes_configuration_example_shows_the_defaults():
    """Its values read as the defaults, and four of them were not (0.5 for -0.5, ...)."""
    import math
    import re

    from fastdet.detector.config import tomllib

    readme = (Path(__file__).parents[2] / "README.md").read_text()
    section = readme[readme.index("## Configuration"):]
    block = re.search(r"```toml\n(.*?)```", section, re.S).group(1)
    block = "\n".join(line for line in block.splitlines() if not line.startswith("refine ="))
    listed = tomllib.loads(block)
    defaults = DetectorConfig()
    for name in ("search", "heat", "boxes"):
        values = dict(listed[name])
        windows = values.pop("windows", [])
        for key, value in values.items():
            expected = getattr(getattr(defaults, name), key)
            expected = list(expected) if isinstance(expected, tuple) else expected
            assert value == expected, f"[{name}] {key} = {value!r}, the default is {expected!r}"
        for window in windows:
            assert any(math.isclose(window["size"], default.size, abs_tol=1e-4)
                       and window["overlap"] == default.overlap
                       for default in defaults.search.windows), window


# -- configurations built in code ------------------------------------------------
@pytest.mark.parametrize("section, value", [("search", {}), ("heat", None),
                                            ("boxes", {"min_size": 3})])
def test_sections_must_be_their_dataclasses(section, value):
    """A dict or None was kept and failed on an attribute in the first detection."""
    with pytest.raises(ConfigError, match=f"{section} must be a "):
        DetectorConfig(**{section: value})


@pytest.mark.parametrize("key, value", [("windows", [{"size": 0.1, "overlap": 0.5}]),
                                        ("scales", [(64, 0.5, (0, 1280), (0, 720))])])
def test_windows_and_scales_must_be_their_dataclasses(key, value):
    with pytest.raises(ConfigError, match=f"search.{key} must hold"):
        SearchConfig(**{key: value, **({"windows": ()} if key == "scales" else {})})


@pytest.mark.parametrize("build, name", [
    (lambda: SearchConfig(windows=None), "search.windows"),
    (lambda: SearchConfig(band=None), "search.band"),
    (lambda: SearchConfig(reference_size=1280), "search.reference_size"),
    (lambda: ScaleConfig(64, 0.5, None, (0, 720)), "search.scales.x"),
    (lambda: ScaleConfig(64, 0.5, (0, 1280), 3), "search.scales.y"),
    (lambda: BoxConfig(refine=None), "boxes.refine"),
    (lambda: BoxConfig(refine=[1, 2, 3, 4]), "boxes.refine"),
])
def test_a_list_setting_given_no_list_names_it(build, name):
    """``tuple(None)``'s "'NoneType' object is not iterable"."""
    with pytest.raises(ConfigError, match=f"{name} must be a list"):
        build()


@pytest.mark.parametrize("data", [[], None, "search"])
def test_from_dict_takes_only_dicts(data):
    with pytest.raises(ConfigError, match="must be a table"):
        DetectorConfig.from_dict(data)


@pytest.mark.parametrize("fraction", ["0.5", "auto", None, True])
def test_with_horizon_takes_only_numbers(fraction):
    """``float()`` read "0.5" and failed on "auto" with its own message."""
    with pytest.raises(ConfigError, match="search.horizon must be a number"):
        DetectorConfig().with_horizon(fraction)
    assert DetectorConfig().with_horizon(np.float32(0.5)).search.horizon == 0.5


@pytest.mark.parametrize("path, error, words", [
    (3, TypeError, "given by its path"),
    (b"config.toml", TypeError, "given by its path"),
    ("", ConfigError, "path is empty"),
    ("/dev/null", ConfigError, "not a regular file"),
])
def test_config_paths_that_are_no_files(path, error, words):
    with pytest.raises(error, match=words):
        load_config(path)


def test_numpy_scalars_are_the_numbers_they_hold():
    """np.float32(0.55) as a horizon was refused as "not a finite number"."""
    import dataclasses

    from fastdet import FeatureOptions, TrackConfig

    config = DetectorConfig()
    search = dataclasses.replace(config.search, horizon=np.float32(0.55),
                                 band=(np.float64(0.5), np.float32(0.9)),
                                 reference_size=(np.int64(1280), np.int32(720)))
    assert type(search.horizon) is float and search.horizon == float(np.float32(0.55))
    assert search.band == (0.5, float(np.float32(0.9))) and search.reference_size == (1280, 720)
    assert all(type(v) is int for v in search.reference_size)
    heat = dataclasses.replace(config.heat, threshold=np.float32(config.heat.threshold))
    assert type(heat.threshold) is float
    options = FeatureOptions(orientations=np.int64(9), hist_bins=np.uint8(32))
    assert options == FeatureOptions(orientations=9, hist_bins=32)
    assert TrackConfig(every=np.int64(3)).every == 3
    # What the equal Python value is refused for, the NumPy one is too.
    with pytest.raises(ConfigError, match="heat.threshold"):
        dataclasses.replace(config.heat, threshold=np.bool_(True))
    with pytest.raises(ConfigError, match="orientations"):
        FeatureOptions(orientations=np.float64(9.5))
