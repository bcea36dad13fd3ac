"""The command line: output formats, and one-line errors with a non-zero exit."""

import json
import os

import cv2
import numpy as np
import pytest

from fastdet.cli.app import EXIT_ERROR, main
from fastdet.detector.features import FeatureLayout, FeatureOptions
from fastdet.detector.model import Model
from training_inputs import make_crops


@pytest.fixture(scope="module")
def model_path(tmp_path_factory):
    """A random (but valid) model whose threshold gives some hits on real frames."""
    options = FeatureOptions()
    rng = np.random.default_rng(11)
    weights = rng.normal(scale=0.01, size=FeatureLayout(options).length).astype(np.float32)
    path = tmp_path_factory.mktemp("model") / "random.npz"
    Model(weights=weights, bias=0.0, options=options).save(path)
    return path


@pytest.fixture
def image(tmp_path, data_dir):
    return data_dir / "test_images" / "test1.jpg"


def one_line_error(capsys):
    err = capsys.readouterr().err.strip()
    assert err.startswith("fastdet: error: "), err
    assert "\n" not in err and "Traceback" not in err
    return err


def test_detect_prints_one_json_object_per_image(capsys, model_path, image, tmp_path):
    code = main(["detect", str(image), str(image), "--model", str(model_path), "--threads", "1",
                 "--out-dir", str(tmp_path / "drawn")])
    assert code == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 2
    record = json.loads(lines[0])
    assert record["image"] == str(image)
    assert set(record) >= {"image", "boxes", "ms"}
    assert record["ms"] > 0
    for box in record["boxes"]:
        x1, y1, x2, y2 = box["box"]
        assert 0 <= x1 < x2 <= 1280 and 0 <= y1 < y2 <= 720
        assert isinstance(box["score"], float)
    drawn = cv2.imread(str(tmp_path / "drawn" / image.name))
    assert drawn is not None and drawn.shape == (720, 1280, 3)


def test_detect_refuses_two_images_drawn_to_one_name(capsys, model_path, image, tmp_path):
    """Two images of one name from two folders: the second drawing replaced the
    first, and both JSON lines named it as their output."""
    other = tmp_path / "other" / image.name
    other.parent.mkdir()
    other.write_bytes(image.read_bytes())
    drawn = tmp_path / "drawn"
    assert main(["detect", str(image), str(other), "--model", str(model_path),
                 "--out-dir", str(drawn)]) == EXIT_ERROR
    assert f"would both be drawn to {drawn / image.name}" in one_line_error(capsys)
    assert list(drawn.iterdir()) == []
    # The same image twice is one drawing.
    assert main(["detect", str(image), str(image), "--model", str(model_path),
                 "--out-dir", str(drawn)]) == 0
    assert [p.name for p in drawn.iterdir()] == [image.name]


@pytest.mark.parametrize("verb, prefix", [("detect", "--out"), ("run", "--detect")])
def test_an_option_given_by_a_prefix_is_refused(capsys, image, tmp_path, verb, prefix):
    """``detect --out x.jpg`` was ``--out-dir x.jpg``: a folder named x.jpg."""
    target = tmp_path / "x.jpg"
    with pytest.raises(SystemExit) as stop:
        main([verb, str(image), prefix, str(target)])
    assert stop.value.code == 2
    assert f"fastdet {verb}: error: unrecognized arguments: {prefix} {target}" \
        in capsys.readouterr().err
    assert not target.exists()


@pytest.mark.parametrize("verb", [["detect"], ["run"], ["viz", "hog"], ["batch", "--out-dir", "o"]])
def test_an_unknown_option_is_refused_with_the_verbs_usage(capsys, verb):
    """argparse hands a verb's unknown arguments up to the top-level parser,
    which printed ``fastdet``'s usage, not the verb's."""
    name = " ".join(word for word in verb if word not in ("--out-dir", "o"))
    with pytest.raises(SystemExit) as stop:
        main([*verb, "input", "--no-such-option", "7"])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith(f"usage: fastdet {name} ")
    assert err.rstrip().endswith(
        f"fastdet {name}: error: unrecognized arguments: --no-such-option 7")


@pytest.mark.parametrize("verb", ["detect", "eval"])
def test_a_bad_track_section_is_refused_by_verbs_that_do_not_track(capsys, data_dir, tmp_path,
                                                                   verb):
    """One config file serves every verb: its [track] mistakes passed detect and eval."""
    config = tmp_path / "bad.toml"
    config.write_text('[track]\nevery = "x"\n')
    images = data_dir / "test_images"
    inputs = ([str(images / "test1.jpg")] if verb == "detect"
              else [str(images / "annotations.json"), str(images)])
    assert main([verb, *inputs, "--config", str(config), "--threads", "1"]) == EXIT_ERROR
    message = one_line_error(capsys)
    assert str(config) in message and "every" in message


@pytest.mark.parametrize("verb", ["eval", "detect"])
def test_a_reader_that_goes_away_ends_the_command_quietly(data_dir, verb):
    """``fastdet eval ... | head -2``: "fastdet: error: [Errno 32] Broken pipe" before."""
    import subprocess
    import sys

    images = data_dir / "test_images"
    inputs = ([str(images / "annotations.json"), str(images)] if verb == "eval"
              else [str(images / "test1.jpg"), str(images / "test2.jpg")])
    read_end, write_end = os.pipe()
    os.close(read_end)          # before the command prints anything
    try:
        done = subprocess.run([sys.executable, "-m", "fastdet.cli", verb, *inputs,
                               "--threads", "1"], stdout=write_end, stderr=subprocess.PIPE,
                              timeout=300)
    finally:
        os.close(write_end)
    assert (done.returncode, done.stderr.decode()) == (141, "")


@pytest.mark.parametrize("argv", [["detect", "x.jpg", "--out-dir", ""], ["detect", ""],
                                  ["run", "v.mp4", "--out", ""], ["eval", "a.json", "", "--json"]])
def test_an_empty_value_is_refused(capsys, argv):
    """``detect --out-dir ''`` was taken as no --out-dir: no drawing and no error."""
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2
    assert "expected a value, got an empty string" in capsys.readouterr().err


def test_detect_missing_image(capsys, model_path, tmp_path):
    assert main(["detect", str(tmp_path / "nope.jpg"), "--model", str(model_path)]) == EXIT_ERROR
    assert "not found" in one_line_error(capsys)


def test_detect_non_image_file(capsys, model_path, tmp_path):
    bogus = tmp_path / "notes.jpg"
    bogus.write_text("not an image")
    assert main(["detect", str(bogus), "--model", str(model_path)]) == EXIT_ERROR
    assert "cannot read" in one_line_error(capsys)


def test_detect_invalid_config(capsys, model_path, image, tmp_path):
    config = tmp_path / "bad.toml"
    config.write_text("[heat]\nthreshhold = 2\n")
    assert main(["detect", str(image), "--model", str(model_path), "--config", str(config)]) \
        == EXIT_ERROR
    assert "threshhold" in one_line_error(capsys)


@pytest.mark.parametrize("damage", ["truncate", "text", "missing"])
def test_detect_damaged_model(capsys, model_path, image, tmp_path, damage):
    target = tmp_path / "model.npz"
    if damage == "truncate":
        data = model_path.read_bytes()
        target.write_bytes(data[: len(data) // 2])
    elif damage == "text":
        target.write_text("hello")
    assert main(["detect", str(image), "--model", str(target)]) == EXIT_ERROR
    one_line_error(capsys)


def test_detect_tiny_image_gives_no_boxes(capsys, model_path, tmp_path):
    tiny = tmp_path / "tiny.png"
    cv2.imwrite(str(tiny), np.zeros((20, 30, 3), np.uint8))
    assert main(["detect", str(tiny), "--model", str(model_path)]) == 0
    assert json.loads(capsys.readouterr().out)["boxes"] == []


def test_eval_prints_the_four_figures(capsys, model_path, data_dir):
    images = data_dir / "test_images"
    code = main(["eval", str(images / "annotations.json"), str(images), "--model", str(model_path),
                 "--json", "--threads", "1"])
    assert code == 0
    report = json.loads(capsys.readouterr().out)
    # The test model may find nothing: then precision and IoU have no denominator.
    assert (report["precision"] is None) == (report["tp"] + report["fp"] == 0)
    assert (report["mean_iou"] is None) == (report["tp"] == 0)
    for key in ("precision", "recall", "ap", "mean_iou"):
        assert report[key] is None or 0.0 <= report[key] <= 1.0
    errors = report["errors"]
    assert sum(errors["false_positives"].values()) == report["fp"]
    assert errors["misses"]["near"] + errors["misses"]["missed"] == report["fn"]


def test_eval_text_report_names_the_kinds_of_error(capsys, data_dir):
    images = data_dir / "test_images"
    assert main(["eval", str(images / "annotations.json"), str(images), "--threads", "1"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[2].startswith("false positives: ") and "on background" in lines[2]
    assert lines[3].startswith("AP50 gained by fixing each kind: duplicate ")


def test_eval_voc_switch_selects_the_plain_rule(capsys, data_dir):
    images = data_dir / "test_images"
    args = ["eval", str(images / "annotations.json"), str(images), "--json", "--threads", "1"]
    assert main(args) == 0
    default = json.loads(capsys.readouterr().out)
    assert main(args + ["--voc"]) == 0
    voc = json.loads(capsys.readouterr().out)
    assert default["difficult_cover"] == 0.5
    assert voc["difficult_cover"] is None
    # The coverage rule only ever ignores detections VOC counts as false (the
    # rule itself is tested in tests/evaluation).
    assert voc["fp"] - default["fp"] == default["ignored"] - voc["ignored"] >= 0
    assert voc["tp"] == default["tp"]


def test_eval_says_n_a_for_figures_without_a_denominator(capsys, data_dir, tmp_path):
    """Frames without vehicles read as recall 1.000 and AP 0.000 before."""
    images = data_dir / "test_images"
    annotations = tmp_path / "empty.json"
    annotations.write_text(json.dumps({"images": {"test1.jpg": []}}))
    assert main(["eval", str(annotations), str(images), "--threads", "1"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("images 1  vehicles 0  TP 0  FP 2")
    assert lines[1] == ("precision 0.000  recall n/a  AP50 n/a  mean IoU n/a  "
                        "IoU 10th percentile n/a")
    assert main(["eval", str(annotations), str(images), "--threads", "1", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert (report["precision"], report["recall"], report["ap"]) == (0.0, None, None)


@pytest.mark.parametrize("content, split, words", [
    ({"images": {}}, None, "no annotated image or frame: nothing to evaluate"),
    ({"images": {"test1.jpg": []}, "frames": {"held_out": []}}, "held_out",
     "no annotated image or frame in split 'held_out': nothing to evaluate")])
def test_eval_refuses_to_evaluate_nothing(capsys, data_dir, tmp_path, content, split, words):
    """An empty "images" object, or a split that lists no image, printed all-n/a figures and
    exited 0."""
    annotations = tmp_path / "nothing.json"
    annotations.write_text(json.dumps(content))
    argv = ["eval", str(annotations), str(data_dir / "test_images"), "--threads", "1"]
    assert main(argv + (["--split", split] if split else [])) == EXIT_ERROR
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.strip() == f"fastdet: error: {annotations}: {words}"


def test_eval_missing_annotations(capsys, model_path, tmp_path):
    assert main(["eval", str(tmp_path / "a.json"), str(tmp_path), "--model", str(model_path)]) \
        == EXIT_ERROR
    one_line_error(capsys)


@pytest.mark.parametrize("iou", ["nan", "inf", "0", "-1", "2"])
def test_eval_refuses_a_match_iou_outside_zero_to_one(capsys, model_path, data_dir, iou):
    """NaN and infinity stopped eval with an internal error after half the report;
    0, -1 and 2 printed an "AP-100"."""
    assert main(["eval", str(data_dir / "test_images" / "annotations.json"),
                 str(data_dir / "test_images"), "--model", str(model_path),
                 "--iou", iou]) == EXIT_ERROR
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.strip() == f"fastdet: error: --iou must be in (0, 1], got {float(iou)}"


@pytest.mark.parametrize("seed", ["-1"])
def test_viz_samples_refuses_a_negative_seed(capsys, data_dir, tmp_path, seed):
    assert main(["viz", "samples", str(data_dir), "--seed", seed,
                 "--out", str(tmp_path / "s.png")]) == EXIT_ERROR
    assert "seed must be a whole number >= 0, got -1" in one_line_error(capsys)
    assert not (tmp_path / "s.png").exists()


def test_train_writes_a_loadable_model(capsys, tmp_path):
    rng = np.random.default_rng(0)
    make_crops(tmp_path / "data" / "vehicles" / "GTI_Far", 1, 30, rng)
    make_crops(tmp_path / "data" / "non-vehicles" / "GTI", 0, 30, rng)
    out = tmp_path / "m.npz"
    code = main(["train", str(tmp_path / "data"), "--out", str(out), "--no-flip",
                 "--spatial-size", "16", "--hist-bins", "16"])
    assert code == 0
    text = capsys.readouterr().out
    assert "leak-free split 1.0000" in text and "random split 1.0000" in text
    from fastdet.detector.model import load_model
    model = load_model(out)
    assert model.options.spatial_size == 16
    assert model.report["crops"] == 60
    assert model.report["jitter_augmentation"] is not None
    assert model.report["photometric_augmentation"]["probability"] == 0.5
    assert model.report["source_holdout"] is None


def test_train_photometric_and_source_holdout_switches(capsys, tmp_path):
    rng = np.random.default_rng(0)
    make_crops(tmp_path / "data" / "vehicles" / "GTI_Far", 1, 20, rng)
    make_crops(tmp_path / "data" / "vehicles" / "KITTI_extracted", 1, 20, rng)
    make_crops(tmp_path / "data" / "non-vehicles" / "GTI", 0, 20, rng)
    make_crops(tmp_path / "data" / "non-vehicles" / "Extras", 0, 20, rng)
    out = tmp_path / "m.npz"
    assert main(["train", str(tmp_path / "data"), "--out", str(out), "--no-flip",
                 "--no-photometric", "--source-holdout", "--spatial-size", "16",
                 "--hist-bins", "16"]) == 0
    text = capsys.readouterr().out
    assert "source KITTI held out: accuracy" in text and "(20 vehicles)" in text
    from fastdet.detector.model import load_model
    report = load_model(out).report
    assert report["photometric_augmentation"] is None
    assert set(report["source_holdout"]) == {"GTI", "KITTI", "Extras"}
    assert report["source_holdout"]["Extras"]["vehicles"] == 0


def test_train_no_jitter_switch(capsys, tmp_path):
    rng = np.random.default_rng(0)
    make_crops(tmp_path / "data" / "vehicles" / "GTI_Far", 1, 30, rng)
    make_crops(tmp_path / "data" / "non-vehicles" / "GTI", 0, 30, rng)
    out = tmp_path / "m.npz"
    assert main(["train", str(tmp_path / "data"), "--out", str(out), "--no-flip", "--no-jitter",
                 "--spatial-size", "16", "--hist-bins", "16"]) == 0
    from fastdet.detector.model import load_model
    assert load_model(out).report["jitter_augmentation"] is None


def test_train_missing_folder(capsys, tmp_path):
    assert main(["train", str(tmp_path), "--out", str(tmp_path / "m.npz")]) == EXIT_ERROR
    assert "not found" in one_line_error(capsys)


def test_train_invalid_option(capsys, tmp_path):
    assert main(["train", str(tmp_path), "--out", str(tmp_path / "m.npz"),
                 "--pixels-per-cell", "7"]) == EXIT_ERROR
    assert "pixels_per_cell" in one_line_error(capsys)
