"""Detector configuration: defaults, TOML overrides and one-line errors."""

from pathlib import Path

import pytest

import fastdet
from fastdet.detector.config import DEFAULT_SCALES, PUBLISHED_SCALES, DetectorConfig, load_config
from fastdet.errors import ConfigError


def write(tmp_path, text):
    path = tmp_path / "config.toml"
    path.write_text(text)
    return path


def test_defaults_are_the_five_published_scales_with_the_64_pixel_one_moved():
    config = load_config(None)
    assert config.search.scales == DEFAULT_SCALES
    assert [s.window for s in config.search.scales] == [32, 48, 64, 112, 128]
    changed = [i for i in range(5) if DEFAULT_SCALES[i] != PUBLISHED_SCALES[i]]
    assert changed == [2]
    assert (DEFAULT_SCALES[2].overlap, DEFAULT_SCALES[2].x, DEFAULT_SCALES[2].y) == (
        0.75, (0, 1280), (396, 500))
    assert PUBLISHED_SCALES[2].x == (426, 853)


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
    assert config.search.scales == DEFAULT_SCALES


def test_scales_replace_the_list(tmp_path):
    config = load_config(write(tmp_path, "[[search.scales]]\nwindow = 80\noverlap = 0.5\n"
                                         "x = [0, 1280]\ny = [380, 600]\n"))
    assert len(config.search.scales) == 1
    assert config.search.scales[0].window == 80


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
    ("[search\n", "not valid TOML"),
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
