"""train, tune, mine and bench refuse bad inputs and outputs at once, in one line.

Every case here once ran the long work first (feature extraction, a grid
search, a benchmark) and then failed, with a traceback (exit 70), after
writing half of its outputs -- or overwrote one of its inputs.
"""

from __future__ import annotations

import json
import os
import tomllib

import cv2
import numpy as np
import pytest

from fastdet.cli.app import EXIT_ERROR, main
from fastdet.detector.config import load_config
from fastdet.detector.detector import Detector
from fastdet.detector.features import FeatureLayout, FeatureOptions
from fastdet.detector.model import Model, load_model
from fastdet.evaluation.annotations import load_annotations
from fastdet.training.tune import tune, tuned_config
from fastdet.video.config import load_track_config
from video_files import write_clip
from training_inputs import annotated_blocks, make_crops


def one_line_error(capsys):
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()[-1] if captured.err.strip() else ""
    assert err.startswith("fastdet: error: "), captured.err
    assert "Traceback" not in captured.err
    return err


@pytest.fixture
def data(tmp_path):
    """Ten crops a class, all from one source (GTI)."""
    rng = np.random.default_rng(0)
    make_crops(tmp_path / "data" / "vehicles" / "GTI_Far", 1, 10, rng)
    make_crops(tmp_path / "data" / "non-vehicles" / "GTI", 0, 10, rng)
    return tmp_path / "data"


FAST = ["--no-flip", "--no-jitter", "--spatial-size", "16", "--hist-bins", "16"]


def crop_bytes(data):
    return {p: p.read_bytes() for p in sorted(data.rglob("*.png"))}


# -- 1. outputs that are inputs ----------------------------------------------
@pytest.mark.parametrize("option,name", [
    ("--out", "vehicles/GTI_Far/image0000.png"),
    ("--report", "vehicles/GTI_Far/image0001.png"),
    ("--out", "non-vehicles/model.npz"),        # a new name, but inside the training data
    ("--report", "vehicles/report.png"),        # would be listed as a crop by the next run
])
def test_train_refuses_to_write_into_its_training_data(capsys, data, tmp_path, option, name):
    before = crop_bytes(data)
    args = ["train", str(data), *FAST, "--out", str(tmp_path / "m.npz")]
    args += [option, str(data / name)]
    assert main(args) == EXIT_ERROR
    err = one_line_error(capsys)
    assert err.startswith(f"fastdet: error: cannot write {data / name}: it is ")
    assert crop_bytes(data) == before
    assert not (tmp_path / "m.npz").exists()


def test_train_refuses_one_name_for_model_and_report(capsys, data, tmp_path):
    out = tmp_path / "both.png"
    assert main(["train", str(data), *FAST, "--out", str(out), "--report", str(out)]) \
        == EXIT_ERROR
    assert "two names" in one_line_error(capsys)
    assert not out.exists()


# -- 2. output names checked before the work ---------------------------------
@pytest.mark.parametrize("report", ["r.txt", "m18.npz"])
def test_train_checks_the_report_name_before_training(capsys, data, tmp_path, report):
    model = tmp_path / "m11.npz"
    assert main(["train", str(data), *FAST, "--out", str(model), "--report",
                 str(tmp_path / report)]) == EXIT_ERROR
    captured = capsys.readouterr()
    assert "cannot write a figure to" in captured.err
    assert "crops (" not in captured.err         # the training's first log line
    assert not model.exists()


def test_train_compare_checks_the_plot_name_before_the_study(capsys, data, tmp_path):
    assert main(["train", str(data), "--compare", "--plot", str(tmp_path / "cmp.txt")]) \
        == EXIT_ERROR
    captured = capsys.readouterr()
    assert captured.out == "" and "cannot write a figure to" in captured.err


@pytest.mark.parametrize("args,message", [
    (["--plot", "p.txt"], "cannot write a figure to"),
    (["--reference-frames", "-1"], "--reference-frames must be 0"),
])
def test_bench_checks_its_arguments_before_timing(capsys, tmp_path, args, message):
    assert main(["bench", "--frames", "1", *args]) == EXIT_ERROR
    captured = capsys.readouterr()
    assert "frames:" not in captured.out           # no frame was read
    assert message in captured.err.strip().splitlines()[-1]


# -- 3. bad numbers -----------------------------------------------------------
@pytest.mark.parametrize("args,message", [
    (["--folds", "1"], "--folds must be at least 2"),
    (["--folds", "0"], "--folds must be at least 2"),
    (["--C", "0"], "--C must be a finite number above 0"),
    (["--C", "-1"], "--C must be a finite number above 0"),
    (["--C", "nan"], "--C must be a finite number above 0"),
    (["--C", "1e-3", "inf"], "--C must be a finite number above 0"),
])
def test_train_refuses_bad_numbers_at_once(capsys, data, tmp_path, args, message):
    out = tmp_path / "m.npz"
    assert main(["train", str(data), *FAST, "--out", str(out), *args]) == EXIT_ERROR
    assert message in one_line_error(capsys)
    assert not out.exists()


def test_source_holdout_of_a_single_source_names_the_sources(capsys, data, tmp_path, monkeypatch):
    from fastdet.training import train

    def no_extraction(*args, **kwargs):
        raise AssertionError("features were extracted before the check")

    monkeypatch.setattr(train, "features_of_crops", no_extraction)
    out = tmp_path / "m.npz"
    assert main(["train", str(data), *FAST, "--out", str(out), "--source-holdout"]) \
        == EXIT_ERROR
    err = one_line_error(capsys)
    assert "--source-holdout" in err and "sources found: GTI" in err
    assert not out.exists()


# -- 8. contradictory options -------------------------------------------------
@pytest.mark.parametrize("args,message", [
    (["--compare", "--out", "cmp.npz"], "--out cannot be used with it"),
    (["--compare", "--report", "r.png"], "--report cannot be used with it"),
    (["--compare", "--cv"], "--cv cannot be used with it"),
    # The study varies these itself (--spatial-size 0 became 32, the others were ignored).
    (["--compare", "--color-space", "YCrCb"], "--color-space cannot be used with it"),
    (["--compare", "--hog-channel", "0"], "--hog-channel cannot be used with it"),
    (["--compare", "--no-hog"], "--no-hog cannot be used with it"),
    (["--compare", "--spatial-size", "0"], "--spatial-size 0 cannot be used with it"),
    (["--compare", "--hist-bins", "0"], "--hist-bins 0 cannot be used with it"),
    (["--compare", "--folds", "3"], "--folds cannot be used with it"),
    (["--plot", "p.png", "--out", "m.npz"], "--plot draws the --compare table"),
])
def test_train_refuses_options_its_mode_would_ignore(capsys, data, tmp_path, args, message):
    args = [str(tmp_path / a) if a.endswith((".npz", ".png")) else a for a in args]
    assert main(["train", str(data), *FAST, *args]) == EXIT_ERROR
    assert message in one_line_error(capsys)
    assert not list(tmp_path.glob("*.npz")) and not list(tmp_path.glob("*.png"))


# -- tune and mine on synthetic frames ---------------------------------------
@pytest.fixture
def generous_model(tmp_path):
    """Calls anything bright a vehicle: bias + mean of the spatial features."""
    options = FeatureOptions(use_hog=False, spatial_size=16, hist_bins=0, color_space="RGB")
    weights = np.full(FeatureLayout(options).length, 1.0 / (16 * 16 * 3), np.float32)
    path = tmp_path / "generous.npz"
    Model(weights, bias=-100.0, options=options).save(path)
    return path


@pytest.fixture
def scene(tmp_path):
    """a.png (a bright, annotated block), b.png (an unannotated one), their annotations."""
    annotations = annotated_blocks(tmp_path)
    return tmp_path, annotations


#: A layout of its own (pixel scales), box filters and [track]: none of them is tuned.
CUSTOM = """\
[search]
reference_size = [256, 128]
margin = 0.0

[[search.scales]]
window = 64
overlap = 0.5
x = [0, 256]
y = [0, 128]

[boxes]
min_size = 8
horizon_y = 0
snap_sides = 0

[track]
every = 2
"""


def test_tune_refuses_sources_without_an_annotated_frame(capsys, scene, generous_model):
    folder, _ = scene
    empty = folder / "empty.json"
    empty.write_text(json.dumps({"images": {}}))
    out = folder / "empty.toml"
    assert main(["tune", str(folder / "a.png"), "--annotations", str(empty), "--model",
                 str(generous_model), "--out", str(out)]) == EXIT_ERROR
    captured = capsys.readouterr()
    assert "no annotated frame found" in captured.err and "precision" not in captured.out
    assert not out.exists()


def test_tune_writes_the_whole_config_with_the_tuned_values(capsys, scene, generous_model):
    folder, annotations = scene
    custom = folder / "custom.toml"
    custom.write_text(CUSTOM)
    out = folder / "tuned.toml"
    assert main(["tune", str(folder / "a.png"), "--annotations", str(annotations), "--model",
                 str(generous_model), "--config", str(custom), "--out", str(out),
                 "--top", "1"]) == 0
    written = tomllib.loads(out.read_text())
    # Nothing of --config is lost ...
    assert written["track"] == {"every": 2}
    assert written["search"]["scales"] == tomllib.loads(CUSTOM)["search"]["scales"]
    assert written["boxes"]["min_size"] == 8
    # ... and the file reproduces the best setting on its own: the same detector
    # settings as the tuning scored, so detect/eval with it match the table.
    base = load_config(custom)
    model = load_model(generous_model)
    truth = {"a.png": load_annotations(annotations)["a.png"]}
    best = tune(model, [folder / "a.png"], truth, base)[0]
    assert load_config(out) == tuned_config(base, best)
    assert load_track_config(out) == load_track_config(custom)
    image = cv2.imread(str(folder / "a.png"))
    from_file = Detector(model, load_config(out), threads=1)(image)
    from_tuning = Detector(model, tuned_config(base, best), threads=1)(image)
    assert np.array_equal(from_file.xyxy, from_tuning.xyxy)


@pytest.mark.parametrize("args,message", [
    (["--top", "0"], "--top must be at least 1"),
    (["--top", "-1"], "--top must be at least 1"),
    (["--jitter", "nan"], "--jitter must be rows between"),
    (["--jitter", "1e9"], "--jitter must be rows between"),
    (["--jitter", "4", "inf"], "--jitter must be rows between"),
])
def test_tune_refuses_a_bad_top_or_jitter(capsys, scene, generous_model, args, message):
    folder, annotations = scene
    assert main(["tune", str(folder / "a.png"), "--annotations", str(annotations), "--model",
                 str(generous_model), *args]) == EXIT_ERROR
    assert message in one_line_error(capsys)


def test_tune_jitter_that_moves_the_horizon_out_of_the_frame_names_jitter(capsys, scene,
                                                                          generous_model):
    folder, annotations = scene
    config = folder / "high.toml"
    config.write_text("[search]\nhorizon = 0.02\n")    # 60 rows up leaves the frame
    assert main(["tune", str(folder / "a.png"), "--annotations", str(annotations), "--model",
                 str(generous_model), "--config", str(config), "--jitter", "60"]) == EXIT_ERROR
    err = one_line_error(capsys)
    assert err.startswith("fastdet: error: --jitter 60 moves the search out of the frame")


@pytest.mark.parametrize("value", ["1.5", "-1", "nan", "0"])
def test_mine_refuses_a_max_iou_outside_zero_to_one(capsys, scene, generous_model, value):
    folder, annotations = scene
    out = folder / "mined"
    assert main(["mine", str(folder / "b.png"), "--annotations", str(annotations), "--out",
                 str(out), "--model", str(generous_model), "--max-iou", value]) == EXIT_ERROR
    assert "--max-iou must be in (0, 1]" in one_line_error(capsys)
    assert not out.exists()


def test_a_failed_mine_leaves_no_out_folder(capsys, scene, generous_model):
    folder, _ = scene
    empty = folder / "empty.json"
    empty.write_text(json.dumps({"images": {}}))
    out = folder / "new" / "mined"
    assert main(["mine", str(folder / "b.png"), "--annotations", str(empty), "--out", str(out),
                 "--model", str(generous_model)]) == EXIT_ERROR
    assert "no annotated frame found" in one_line_error(capsys)
    assert not (folder / "new").exists()


def test_mine_says_a_folder_is_not_a_source(capsys, scene, generous_model):
    folder, annotations = scene
    out = folder / "mined"
    assert main(["mine", str(folder), "--annotations", str(annotations), "--out", str(out),
                 "--model", str(generous_model)]) == EXIT_ERROR
    err = one_line_error(capsys)
    assert "is a folder" in err and "not found" not in err
    assert not out.exists()


@pytest.mark.parametrize("verb", ["mine", "tune"])
def test_an_annotated_frame_past_the_videos_end_is_refused(capsys, tmp_path, generous_model,
                                                         verb):
    video = write_clip(tmp_path / "short.mp4", 6)
    annotations = tmp_path / "beyond.json"
    annotations.write_text(json.dumps({"images": {"frame0": [], "frame5000": []}}))
    out = tmp_path / ("mined" if verb == "mine" else "tuned.toml")
    assert main([verb, str(video), "--annotations", str(annotations), "--out", str(out),
                 "--model", str(generous_model)]) == EXIT_ERROR
    err = one_line_error(capsys)
    assert "ends before its annotated frame frame5000" in err
    assert not out.exists()


# -- too few crops, names that clash, names checked first -----------------------
@pytest.mark.parametrize("extra", [[], ["--compare"]])
def test_train_refuses_one_crop_a_class_in_one_line(capsys, tmp_path, extra):
    """One crop a class left the fit nothing to train on: an internal error (exit 70)."""
    rng = np.random.default_rng(0)
    make_crops(tmp_path / "one" / "vehicles", 1, 1, rng)
    make_crops(tmp_path / "one" / "non-vehicles", 0, 1, rng)
    out = [] if extra else ["--out", str(tmp_path / "m.npz")]
    assert main(["train", str(tmp_path / "one"), *FAST, *out, *extra]) == EXIT_ERROR
    assert f"too few crops in {tmp_path / 'one'}" in one_line_error(capsys)
    assert not (tmp_path / "m.npz").exists()


def test_mine_writes_every_crop_of_two_sources_of_one_name(capsys, tmp_path,
                                                             generous_model):
    """day1/b.png and day2/b.png: the second's crops replaced the first's, the count lied."""
    sources, annotation_files = [], []
    for day in ("day1", "day2"):
        (tmp_path / day).mkdir()
        annotation_files.append(str(annotated_blocks(tmp_path / day)))
        sources.append(str(tmp_path / day / "b.png"))
    out = tmp_path / "mined"
    assert main(["mine", *sources, "--annotations", *annotation_files, "--out", str(out),
                 "--model", str(generous_model)]) == 0
    written = len(list(out.iterdir()))
    assert capsys.readouterr().out.startswith(f"{written} hard negatives from ")
    assert written > 0 and len(list(out.glob("b-2_b.png_*.png"))) == written // 2


def test_detect_checks_every_image_name_before_any_work(capsys, tmp_path, generous_model):
    """A missing last name stopped detect after every other image was searched and drawn."""
    annotated_blocks(tmp_path)
    folder = tmp_path
    os.mkfifo(tmp_path / "pipe.png")
    out = tmp_path / "drawn"
    for bad, message in ((tmp_path / "nope.png", "image not found"),
                         ("-", "not standard input ('-')"),
                         (tmp_path / "pipe.png", "is not a regular file")):
        assert main(["detect", str(folder / "a.png"), str(bad), "--out-dir", str(out),
                     "--model", str(generous_model)]) == EXIT_ERROR
        captured = capsys.readouterr()
        assert message in captured.err and captured.err.startswith("fastdet: error: ")
        assert captured.out == ""                  # no image was searched
        assert not out.exists()


def test_detect_refuses_a_drawing_name_opencv_cannot_write_before_any_work(capsys, tmp_path,
                                                                          generous_model):
    """An image named without a suffix was searched; only writing its drawing failed."""
    annotated_blocks(tmp_path)
    (tmp_path / "frame").write_bytes((tmp_path / "b.png").read_bytes())
    out = tmp_path / "drawn"
    assert main(["detect", str(tmp_path / "a.png"), str(tmp_path / "frame"), "--out-dir",
                 str(out), "--model", str(generous_model)]) == EXIT_ERROR
    captured = capsys.readouterr()
    assert captured.out == "" and not out.exists()
    assert captured.err.startswith(f"fastdet: error: cannot draw {tmp_path / 'frame'} to ")
    assert "no writer for 'a name without a suffix'" in captured.err
    # Without --out-dir nothing is written, and the image is read by its content.
    assert main(["detect", str(tmp_path / "frame"), "--model", str(generous_model)]) == 0


@pytest.mark.parametrize("verb", ["mine", "tune"])
def test_a_split_the_file_does_not_name_is_refused_naming_the_file(tmp_path, capsys, verb):
    """The message named no file: with one annotation file a source, which one lacked it?"""
    annotations = annotated_blocks(tmp_path)
    data = json.loads(annotations.read_text())
    data["frames"] = {"development": ["a.png"]}
    annotations.write_text(json.dumps(data))
    out = tmp_path / ("crops" if verb == "mine" else "tuned.toml")
    assert main([verb, str(tmp_path / "a.png"), "--annotations", str(annotations),
                 "--split", "held_out", "--out", str(out)]) == EXIT_ERROR
    assert one_line_error(capsys) == (f"fastdet: error: no split 'held_out' in {annotations} "
                                      f"(splits: development)")
    assert not out.exists()
