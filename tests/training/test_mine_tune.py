"""Hard-negative mining and threshold tuning on annotated frames."""

import json

import cv2
import numpy as np
import pytest

from fastdet.cli.app import EXIT_ERROR, main
from fastdet.detector.config import DetectorConfig, SearchConfig
from fastdet.detector.detector import Detector
from fastdet.detector.features import FeatureLayout, FeatureOptions
from fastdet.detector.model import Model
from fastdet.evaluation.annotations import load_annotations
from fastdet.training.mine import background_hits, mine
from fastdet.errors import ConfigError
from fastdet.training.tune import _moved, as_toml, tune
from training_inputs import annotated_blocks


def test_background_hits_rules():
    vehicles = np.array([[100, 100, 300, 200]])
    boxes = np.array([
        [0, 0, 50, 50],        # far away: background
        [100, 100, 300, 200],  # the vehicle itself
        [120, 120, 152, 152],  # small window on the vehicle: IoU < 0.1 but fully on it
        [280, 150, 380, 250],  # a corner overlap: IoU 0.03, a tenth of the window
        [200, 120, 300, 220],  # IoU 0.36
    ])
    assert background_hits(boxes, vehicles).tolist() == [True, False, False, True, False]
    assert background_hits(boxes, np.zeros((0, 4))).all()


@pytest.fixture(scope="module")
def generous_model():
    """A model that calls anything bright a vehicle: bias + mean of the spatial features."""
    options = FeatureOptions(use_hog=False, spatial_size=16, hist_bins=0, color_space="RGB")
    weights = np.full(FeatureLayout(options).length, 1.0 / (16 * 16 * 3), np.float32)
    return Model(weights, bias=-100.0, options=options)


def small_config():
    from fastdet.detector.config import BoxConfig, HeatConfig, ScaleConfig
    return DetectorConfig(
        search=SearchConfig(scales=(ScaleConfig(64, 0.5, (0, 256), (0, 128)),),
                            reference_size=(256, 128), decision_threshold=0.0),
        heat=HeatConfig(threshold=0.5), boxes=BoxConfig(min_size=8, horizon_y=0))


def test_mine_saves_only_unannotated_hits(tmp_path, generous_model):
    annotations = load_annotations(annotated_blocks(tmp_path))
    detector = Detector(generous_model, small_config(), threads=1)
    sources = [tmp_path / "a.png", tmp_path / "b.png"]
    result = mine(detector, sources, annotations, tmp_path / "out")
    assert result.frames == 2
    # In a.png the block is annotated; in b.png the same block is a false hit.
    assert result.saved and all(p.name.startswith("b_") for p in result.saved)
    crop = cv2.imread(str(result.saved[0]))
    assert crop.shape == (64, 64, 3)


def test_mine_cli_without_annotated_frames(tmp_path, capsys, generous_model):
    model_path = tmp_path / "m.npz"
    generous_model.save(model_path)
    annotations = tmp_path / "a.json"
    annotations.write_text(json.dumps({"images": {"other.png": []}}))
    image = tmp_path / "x.png"
    cv2.imwrite(str(image), np.zeros((64, 64, 3), np.uint8))
    code = main(["mine", str(image), "--annotations", str(annotations), "--out",
                 str(tmp_path / "o"), "--model", str(model_path)])
    assert code == EXIT_ERROR
    assert "no annotated frame" in capsys.readouterr().err


def test_tune_finds_a_perfect_setting_and_writes_toml(tmp_path, generous_model):
    annotations = load_annotations(annotated_blocks(tmp_path))
    # Only a.png: there the bright block is the vehicle.  At threshold 50 only the
    # window on the block is a hit; at 200 none is.
    truth = {"a.png": annotations["a.png"]}
    results = tune(generous_model, [tmp_path / "a.png"], truth, small_config(),
                   grid={"decision_threshold": (50.0, 200.0), "heat_threshold": (0.5,),
                         "weighting": ("count",), "peak_fraction": (0.0,)})
    best = results[0]
    assert best.recall == 1.0 and best.precision == 1.0
    assert best.decision_threshold == 50.0
    assert {r.recall for r in results if r.decision_threshold == 200.0} == {0.0}
    # Results are sorted best first.
    keys = [r.key() for r in results]
    assert keys == sorted(keys, reverse=True)
    text = as_toml(best)
    import tomllib

    from fastdet.detector.config import DetectorConfig as Config
    parsed = Config.from_dict(tomllib.loads(text))
    assert parsed.search.decision_threshold == 50.0
    assert parsed.boxes.width_scale == best.width_scale
    assert parsed.heat.split_min_size == best.split_min_size
    # The refinement fitted to the best setting competes in the same ranking;
    # when it leads, its weights go into the TOML.
    assert any(r.refine for r in results) or all(r.refine_samples == 0 for r in results)
    if best.refine:
        assert parsed.boxes.refine == best.refine


def test_each_source_keeps_its_own_annotations(tmp_path, generous_model):
    """Two sources whose frames share a name: each is scored against its own truth."""
    folders = [tmp_path / "one", tmp_path / "two"]
    for folder in folders:
        folder.mkdir()
    image = np.zeros((128, 256, 3), np.uint8)
    image[32:96, 64:128] = 250
    for folder in folders:
        cv2.imwrite(str(folder / "a.png"), image)
    block = [{"box": [64.0, 32.0, 128.0, 96.0], "label": "car", "difficult": False, "id": 1}]
    # In the second source the block is not a vehicle: a hit there is a false positive.
    sources = [(folders[0] / "a.png", {"a.png": block}), (folders[1] / "a.png", {"a.png": []})]
    results = tune(generous_model, sources, None, small_config(),
                   grid={"decision_threshold": (50.0,), "heat_threshold": (0.5,),
                         "weighting": ("count",), "peak_fraction": (0.0,)})
    first = [r for r in results if not r.refine][0]
    assert (first.recall, first.precision) == (1.0, 0.5)
    detector = Detector(generous_model, small_config(), threads=1)
    # Mining both saves exactly what mining the second alone does: the block is a
    # vehicle in the first.
    both = mine(detector, sources, None, tmp_path / "both")
    second = mine(detector, sources[1:], None, tmp_path / "second")
    assert both.frames == 2 and len(both.saved) == len(second.saved) > 0


def test_mine_cli_takes_only_the_split_asked_for(tmp_path, capsys, generous_model):
    model_path = tmp_path / "m.npz"
    generous_model.save(model_path)
    image = np.zeros((128, 256, 3), np.uint8)
    image[32:96, 64:128] = 250
    for name in ("dev.png", "held.png"):
        cv2.imwrite(str(tmp_path / name), image)
    annotations = tmp_path / "a.json"
    annotations.write_text(json.dumps({"images": {"dev.png": [], "held.png": []},
                                       "frames": {"development": ["dev.png"],
                                                  "held_out": ["held.png"]}}))
    config = tmp_path / "c.toml"
    config.write_text("[search]\ndecision_threshold = 0.0\nreference_size = [256, 128]\n"
                      "[[search.scales]]\nwindow = 64\noverlap = 0.5\nx = [0, 256]\ny = [0, 128]\n")
    out = tmp_path / "mined"
    assert main(["mine", str(tmp_path / "dev.png"), str(tmp_path / "held.png"), "--annotations",
                 str(annotations), "--split", "development", "--out", str(out), "--model",
                 str(model_path), "--config", str(config)]) == 0
    names = sorted(p.name for p in out.iterdir())
    assert names and all(name.startswith("dev_") for name in names)
    assert "1 annotated frames" in capsys.readouterr().out
    # One annotation file per source, or one for all: anything else is refused.
    assert main(["mine", str(tmp_path / "dev.png"), "--annotations", str(annotations),
                 str(annotations), "--out", str(out), "--model", str(model_path)]) == EXIT_ERROR
    assert "one per source" in capsys.readouterr().err


def test_jitter_scores_every_frame_at_each_grid_shift(tmp_path, generous_model):
    """A jittered frame counts once as it is and once with the grid moved 16 rows
    down: there the windows (a step of 32) straddle the block, the box misses it,
    and precision and recall over both samples are a half."""
    annotations = load_annotations(annotated_blocks(tmp_path))
    truth = {"a.png": annotations["a.png"]}
    grid = {"decision_threshold": (50.0,), "heat_threshold": (0.5,), "weighting": ("count",),
            "peak_fraction": (0.0,)}
    config = small_config()

    def first(results):
        return [r for r in results if not r.refine and r.width_scale == 1.5
                and r.height_scale == 1.0 and r.center_dy == 0.0][0]

    still = first(tune(generous_model, [tmp_path / "a.png"], truth, config, grid=grid))
    moved = first(tune(generous_model, [tmp_path / "a.png"], truth, _moved(config, 16), grid=grid))
    both = first(tune(generous_model, [tmp_path / "a.png"], truth, config, grid=grid,
                      jitter=(16,)))
    assert (still.precision, still.recall) == (1.0, 1.0)
    assert (moved.precision, moved.recall) == (0.0, 0.0)
    assert (both.precision, both.recall) == (0.5, 0.5)
    assert both.mean_iou == still.mean_iou      # of the matched boxes: the unmoved one
    search = _moved(config, -8).search
    assert [s.y for s in search.scales] == [(-8, 120)]
    frame_relative = _moved(DetectorConfig(), 7.2).search
    assert frame_relative.horizon == pytest.approx(DetectorConfig().search.horizon + 0.01)


def test_tune_refuses_an_auto_horizon(tmp_path, generous_model):
    annotations = load_annotations(annotated_blocks(tmp_path))
    config = DetectorConfig.from_dict({"search": {"horizon": "auto"}})
    with pytest.raises(ConfigError, match="numeric horizon"):
        tune(generous_model, [tmp_path / "a.png"], annotations, config)
