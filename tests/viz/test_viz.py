"""``fastdet viz`` and the pictures of :mod:`fastdet.viz`.

Each figure is checked for what a reader of it relies on: the file exists,
has the documented pixel size, and is not blank.  Bad inputs must fail with
an :class:`InputError` (one line at the command line) and write nothing.
"""

from __future__ import annotations

import argparse
import json
import sys

import cv2
import numpy as np
import pytest

from fastdet.cli.viz import add_viz_parser
from fastdet.detector.detections import Detections
from fastdet.detector.features import FeatureLayout, FeatureOptions
from fastdet.detector.model import Model
from fastdet.errors import InputError, MissingExtraError, ModelError
from fastdet.viz.data_figures import (
    FEATURES_FIGURE_SIZE,
    glyph_cell_px,
    hog_figure,
    hog_glyphs,
    samples_figure,
    samples_figure_size,
)
from fastdet.viz.draw import debug_frame
from fastdet.viz.training_figures import TRAINING_REPORT_SIZE, training_report_figure

#: A figure whose grey levels vary less than this is taken as blank.
MIN_PIXEL_STD = 10.0


@pytest.fixture(scope="module")
def model_path(tmp_path_factory):
    """A small random model with the default feature options, saved to disk."""
    options = FeatureOptions()
    rng = np.random.default_rng(5)
    weights = rng.normal(scale=0.01, size=FeatureLayout(options).length).astype(np.float32)
    path = tmp_path_factory.mktemp("model") / "random.npz"
    Model(weights=weights, bias=-0.5, options=options).save(path)
    return path


@pytest.fixture(scope="module")
def frame_path(data_dir):
    # Absolute: some tests change the working folder.
    return (data_dir / "test_images" / "test1.jpg").resolve()


@pytest.fixture(scope="module")
def crop_path(data_dir):
    return sorted((data_dir / "vehicles" / "GTI_Far").glob("*.png"))[0].resolve()


@pytest.fixture(scope="module")
def dataset(data_dir):
    from fastdet.training.dataset import list_dataset

    return list_dataset(data_dir)


def run_viz(argv):
    """Parse ``fastdet viz ...`` with the real sub-parsers and run the handler."""
    parser = argparse.ArgumentParser(prog="fastdet")
    add_viz_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["viz", *map(str, argv)])
    return args.handler(args)


def assert_figure(path, size):
    """``path`` is a readable image of ``(width, height)`` that is not blank."""
    assert path.is_file(), f"{path} was not written"
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    assert image is not None, f"{path} is not a readable image"
    assert (image.shape[1], image.shape[0]) == size
    assert image.std() > MIN_PIXEL_STD, f"{path} looks blank (std {image.std():.1f})"
    # Atomic writes leave no temporary files behind.
    assert not list(path.parent.glob(".*.part*"))


# -- each command writes its figure -------------------------------------------
def test_samples(data_dir, tmp_path, capsys):
    out = tmp_path / "samples.png"
    assert run_viz(["samples", data_dir, "--n", 3, "--seed", 1, "--out", out]) == 0
    assert capsys.readouterr().out.strip() == str(out)
    assert samples_figure_size(3) == (490, 400)
    assert_figure(out, (490, 400))


def test_samples_seed_fixes_the_choice(dataset, tmp_path):
    paths = [tmp_path / f"{name}.png" for name in ("a", "b", "c")]
    for path, seed in zip(paths, (7, 7, 8)):
        samples_figure(dataset, path, n=2, seed=seed)
    first, again, other = (cv2.imread(str(path)) for path in paths)
    assert np.array_equal(first, again)
    assert not np.array_equal(first, other)


def test_hog_of_a_crop(model_path, crop_path, tmp_path):
    out = tmp_path / "hog.png"
    run_viz(["hog", crop_path, "--model", model_path, "--out", out])
    # Image + Y, Cr, Cb glyphs in a 2x2 grid of 480-pixel panels.
    assert_figure(out, (960, 1060))


@pytest.mark.parametrize("cells_shape, panel, expected", [
    ((8, 8), (480, 480), 60),         # a 64x64 crop: as before
    ((90, 160), (1280, 720), 8),      # a 1280x720 frame: as before
    ((1250, 1), (480, 1920), 8),      # 10 pixels wide, 10000 tall: was 480 a cell
    ((1, 1250), (1280, 320), 8),
    ((1, 1), (480, 480), 480),
])
def test_glyph_cells_fit_the_panel(cells_shape, panel, expected):
    assert glyph_cell_px(cells_shape, panel, 8) == expected


def test_glyph_picture_is_at_most_about_the_panel_or_the_image():
    """At most 1.27 x the panel's pixels (the cell side rounded up, from over 8), or 8 pixels
    a cell, whatever the image's shape."""
    rng = np.random.default_rng(0)
    for _ in range(500):
        rows, cols = (int(v) for v in rng.integers(1, 3000, 2))
        panel = (int(rng.integers(480, 1281)), int(rng.integers(120, 5121)))
        side = glyph_cell_px((rows, cols), panel, 8)
        assert side >= 8
        assert rows * cols * side ** 2 <= max(1.27 * panel[0] * panel[1], rows * cols * 64)


def test_hog_of_a_tall_thin_image(tmp_path):
    """10 pixels wide: the glyphs were sized by the width alone (a 2.6 GB stamp array)."""
    image = np.random.default_rng(1).integers(0, 256, (4000, 10, 3), dtype=np.uint8)
    out = tmp_path / "tall.png"
    hog_figure(image, FeatureOptions(hog_channel="gray"), out)
    assert_figure(out, (960, 1990))


def test_hog_of_one_channel(crop_path, tmp_path):
    out = tmp_path / "hog_grey.png"
    hog_figure(cv2.imread(str(crop_path)), FeatureOptions(hog_channel="gray"), out)
    assert_figure(out, (960, 550))


def test_features(model_path, crop_path, frame_path, tmp_path):
    for image in (crop_path, frame_path):  # a 64x64 crop, and a frame resized to one
        out = tmp_path / f"features_{image.stem}.png"
        run_viz(["features", image, "--model", model_path, "--out", out])
        assert_figure(out, FEATURES_FIGURE_SIZE)
    assert FEATURES_FIGURE_SIZE == (1400, 900)


def test_windows(model_path, frame_path, tmp_path):
    out = tmp_path / "windows.png"
    run_viz(["windows", frame_path, "--model", model_path, "--out", out])
    assert_figure(out, (1280, 720))


def test_detect(model_path, frame_path, data_dir, tmp_path):
    out = tmp_path / "detect.png"
    run_viz(["detect", frame_path, "--model", model_path, "--out", out,
             "--annotations", data_dir / "test_images" / "annotations.json"])
    # Four 1420-pixel-wide panels of the searched band (+- 16 rows): rows 310-536.
    from fastdet.detector.config import DetectorConfig
    from fastdet.detector.features import FeatureOptions
    from fastdet.detector.plan import plan_scales
    from fastdet.viz.search_figures import detect_figure_size
    plans = plan_scales(DetectorConfig(), FeatureOptions(), (1280, 720))
    size = detect_figure_size((720, 1280, 3), plans)
    assert size == (1600, 1148)
    assert_figure(out, size)


def test_figures_of_frames_far_taller_than_wide_are_refused():
    """A 10x10000 frame asked matplotlib for a canvas millions of pixels tall
    (``std::bad_alloc``, an internal error)."""
    from fastdet.detector.config import DetectorConfig
    from fastdet.detector.features import FeatureOptions
    from fastdet.detector.plan import plan_scales
    from fastdet.errors import InputError
    from fastdet.viz.search_figures import detect_figure_size, windows_figure_size

    plans = plan_scales(DetectorConfig(), FeatureOptions(), (10, 10000))
    with pytest.raises(InputError, match="10x10000 frame would be .* pixels tall"):
        detect_figure_size((10000, 10, 3), plans)
    with pytest.raises(InputError, match="too tall for its width"):
        windows_figure_size((10000, 10, 3))
    assert windows_figure_size((1280, 720, 3)) == (1280, 2276)   # taller than wide: drawn


def test_detect_figure_asks_the_verdict_of_every_final_box(model_path, frame_path, tmp_path):
    from fastdet.detector.detector import Detector
    from fastdet.detector.model import load_model
    from fastdet.files.images import read_image
    from fastdet.viz.search_figures import VERDICT_COLOURS, detect_figure

    detector = Detector(load_model(model_path))
    frame = read_image(frame_path)
    asked = []

    def verdicts(boxes, scores):
        asked.append((np.array(boxes), np.array(scores)))
        return ["match", "background"][:len(boxes)] + ["ignored"] * (len(boxes) - 2)

    detect_figure(frame, detector, tmp_path / "d.png", verdicts=verdicts)
    expected = detector(frame)
    assert len(asked) == 1 and len(expected) > 0
    np.testing.assert_array_equal(asked[0][0], expected.xyxy)
    np.testing.assert_array_equal(asked[0][1], expected.score)
    assert {"match", "ignored", "duplicate", "localisation", "difficult",
            "background"} == set(VERDICT_COLOURS)


def test_viz_detect_judges_boxes_by_the_eval_rules(model_path, frame_path, data_dir, tmp_path,
                                                   monkeypatch):
    import fastdet.viz.search_figures as search_figures

    seen = {}

    def capture(frame, detector, path, ground_truth=None, verdicts=None):
        seen["truth"], seen["verdicts"] = ground_truth, verdicts
        return path

    monkeypatch.setattr(search_figures, "detect_figure", capture)
    run_viz(["detect", frame_path, "--model", model_path, "--out", tmp_path / "d.png",
             "--annotations", data_dir / "test_images" / "annotations.json"])
    truth = [obj for obj in seen["truth"] if not obj["difficult"]]
    boxes = np.array([obj["box"] for obj in truth] + [[0, 0, 5, 5]], float)
    assert seen["verdicts"](boxes, np.ones(len(boxes))) == ["match"] * len(truth) + ["background"]


def test_default_output_names(model_path, frame_path, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    run_viz(["windows", frame_path, "--model", model_path])
    assert capsys.readouterr().out.strip() == "viz_windows_test1.png"
    assert (tmp_path / "viz_windows_test1.png").is_file()


def test_svg_output_follows_the_suffix(model_path, frame_path, tmp_path):
    out = tmp_path / "windows.svg"
    run_viz(["windows", frame_path, "--model", model_path, "--out", out])
    assert out.read_text()[:200].lstrip().startswith("<?xml")


# -- library figures for other commands ---------------------------------------
def test_training_report_figure(tmp_path):
    rng = np.random.default_rng(0)
    labels = np.repeat([1, 0], 300)
    scores = np.where(labels == 1, 2.0, -2.0) + rng.normal(size=labels.size)
    report = {"random_split": {"accuracy": 0.99, "test_crops": 600},
              "leak_free_split": {"accuracy": 0.97, "test_crops": 600}, "crops": 3000,
              "C": 0.001, "cross_validation": {"C": 0.001, "threshold": 0.2},
              "nested": {"ignored": True}}
    out = training_report_figure(report, scores, labels, tmp_path / "report.png")
    assert_figure(out, TRAINING_REPORT_SIZE)
    assert TRAINING_REPORT_SIZE == (1500, 520)


@pytest.mark.parametrize("scores, labels, words", [
    ([], [], "one label per test score"),
    ([0.1, 0.2], [1], "one label per test score"),
    ([0.1, np.nan], [1, 0], "finite"),
    ([0.1, 0.2], [1, 2], "1 \\(vehicle\\)"),
])
def test_training_report_rejects_bad_scores(tmp_path, scores, labels, words):
    out = tmp_path / "report.png"
    with pytest.raises(InputError, match=words):
        training_report_figure({}, scores, labels, out)
    assert not out.exists()


def test_debug_frame(frame_path):
    frame = cv2.imread(str(frame_path))
    detections = Detections([[800, 400, 950, 500]], [3.0])
    heat = np.zeros(frame.shape[:2], np.float32)
    heat[400:500, 800:950] = 3.0
    before = frame.copy()
    shown = debug_frame(frame, detections, heat, {"cells": 12.5, "total": 40.0})
    assert shown.shape == frame.shape and shown.dtype == np.uint8
    assert np.array_equal(frame, before), "the input frame must not be drawn on"
    changed = np.any(shown != frame, axis=2)
    assert changed[:60, :150].mean() > 0.3, "timings box missing from the top-left corner"
    assert changed[4:180, 1280 - 324:1276].mean() > 0.5, "heat inset missing from the top right"
    assert changed[400, 800:950].any(), "detection box not drawn"
    # The inset shows the hot region brightly (inferno: bright is red/yellow).
    inset = shown[4:184, 956:1276]
    assert inset[..., 2].max() > 200


def test_debug_frame_without_heat_or_boxes():
    frame = np.full((90, 160, 3), 80, np.uint8)
    for heat in (None, np.zeros((0, 0), np.float32)):
        shown = debug_frame(frame, Detections.empty(), heat, {})
        assert shown.shape == frame.shape


def test_debug_frame_rejects_a_bad_heat_map():
    with pytest.raises(InputError, match="2-D"):
        debug_frame(np.zeros((90, 160, 3), np.uint8), Detections.empty(),
                        np.zeros((2, 3, 4), np.float32), {})


# -- HOG glyphs ---------------------------------------------------------------
def test_glyphs_run_along_edges():
    """A vertical edge (horizontal gradient) gives vertical glyphs, and vice versa."""
    cell_px = 24
    for axis in (1, 0):
        image = np.zeros((32, 32, 1), np.uint8)
        if axis == 1:
            image[:, 16:] = 200  # vertical edge
        else:
            image[16:] = 200  # horizontal edge
        from fastdet.kernels.hog import cell_histograms
        cells = cell_histograms(image, (8, 8), 9)[:, :, 0]
        glyphs = hog_glyphs(cells, cell_px)
        assert glyphs.shape == (4 * cell_px, 4 * cell_px)
        # The cell left of / above the edge holds one line through its centre.
        cell = glyphs[cell_px:2 * cell_px, cell_px:2 * cell_px]
        rows, cols = np.nonzero(cell > 0.5)
        spread_y, spread_x = np.ptp(rows), np.ptp(cols)
        if axis == 1:
            assert spread_y > 3 * spread_x
        else:
            assert spread_x > 3 * spread_y


def test_glyph_length_follows_the_bin_value():
    cells = np.zeros((1, 2, 9), np.float32)
    cells[0, 0, 4] = 1.0
    cells[0, 1, 4] = 0.5
    glyphs = hog_glyphs(cells, 32)
    strong, weak = (glyphs[:, :32] > 0.5).sum(), (glyphs[:, 32:] > 0.5).sum()
    assert 1.6 < strong / weak < 2.4


# -- bad input ----------------------------------------------------------------
@pytest.mark.parametrize("command", ["hog", "features", "windows", "detect"])
def test_missing_image(model_path, tmp_path, command):
    out = tmp_path / "out.png"
    with pytest.raises(InputError, match="image not found"):
        run_viz([command, tmp_path / "nope.jpg", "--model", model_path, "--out", out])
    assert not out.exists()


@pytest.mark.parametrize("command", ["hog", "features", "windows", "detect"])
def test_unreadable_image(model_path, tmp_path, command):
    bad = tmp_path / "bad.png"
    bad.write_text("not an image")
    with pytest.raises(InputError, match="cannot read"):
        run_viz([command, bad, "--model", model_path, "--out", tmp_path / "out.png"])


def test_missing_data_dir(tmp_path):
    with pytest.raises(InputError, match="data folder not found"):
        run_viz(["samples", tmp_path / "nope", "--out", tmp_path / "out.png"])


def test_data_dir_without_class_folders(tmp_path):
    (tmp_path / "data").mkdir()
    with pytest.raises(InputError, match="vehicles"):
        run_viz(["samples", tmp_path / "data", "--out", tmp_path / "out.png"])


@pytest.mark.parametrize("n", [0, -3, 257])
def test_bad_sample_count(dataset, tmp_path, n):
    with pytest.raises(InputError, match="1..256"):
        samples_figure(dataset, tmp_path / "out.png", n=n)


def test_missing_model(frame_path, tmp_path):
    with pytest.raises(ModelError, match="not found"):
        run_viz(["windows", frame_path, "--model", tmp_path / "nope.npz",
                 "--out", tmp_path / "out.png"])


@pytest.mark.parametrize("name, words", [("out.xyz", "must end in one of"),
                                         ("missing/out.png", "output folder not found")])
def test_bad_output_path(model_path, frame_path, tmp_path, name, words):
    with pytest.raises(InputError, match=words):
        run_viz(["windows", frame_path, "--model", model_path, "--out", tmp_path / name])


def test_annotations_without_the_frame(model_path, frame_path, tmp_path):
    annotations = tmp_path / "a.json"
    annotations.write_text(json.dumps({"images": {"other.jpg": []}}))
    with pytest.raises(InputError, match="no entry for test1.jpg"):
        run_viz(["detect", frame_path, "--model", model_path, "--annotations", annotations,
                 "--out", tmp_path / "out.png"])


def test_frame_smaller_than_every_window(model_path, tmp_path):
    # Windows scale with the frame height; on a 30-row frame every one is
    # below the 16 pixels the search bothers with.
    tiny = tmp_path / "tiny.png"
    cv2.imwrite(str(tiny), np.zeros((30, 1000, 3), np.uint8))
    with pytest.raises(InputError, match="smaller than every search window"):
        run_viz(["windows", tiny, "--model", model_path, "--out", tmp_path / "out.png"])


def test_missing_matplotlib_is_one_clear_error(frame_path, model_path, tmp_path, monkeypatch):
    for name in ("matplotlib", "matplotlib.figure", "matplotlib.backend_bases",
                 "matplotlib.backends.backend_agg"):
        monkeypatch.setitem(sys.modules, name, None)  # makes `import` raise ImportError
    for name in [m for m in sys.modules if m.startswith("fastdet.viz.") and "figure" in m]:
        monkeypatch.delitem(sys.modules, name)  # imported afresh, as in a new process
    with pytest.raises(MissingExtraError, match=r"pip install 'fastdet\[viz\]'"):
        run_viz(["windows", frame_path, "--model", model_path, "--out", tmp_path / "out.png"])


def test_errors_reach_the_command_line_as_one_line(tmp_path, capsys):
    from fastdet.cli.app import build_parser, main

    assert "viz" in build_parser()._subparsers._group_actions[0].choices
    assert main(["viz", "hog", str(tmp_path / "nope.jpg")]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and error.startswith("fastdet: error: image not found")


# -- drawing on yuv420p planes ------------------------------------------------------------
def test_bgr_to_yuv_matches_opencv_bt601():
    from fastdet.viz.draw import bgr_to_yuv

    for colour in ((255, 255, 255), (0, 0, 0), (0, 0, 255), (0, 200, 0), (255, 0, 0),
                   (0, 128, 255)):
        patch = np.full((2, 2, 3), colour, np.uint8)
        i420 = cv2.cvtColor(patch, cv2.COLOR_BGR2YUV_I420).ravel()   # Y x4, U, V
        assert np.abs(np.array(bgr_to_yuv(colour)) - i420[[0, 4, 5]]).max() <= 1
    assert bgr_to_yuv((255, 255, 255), bt709=True) == (235, 128, 128)


def test_boxes_drawn_on_yuv_planes_look_like_boxes_drawn_on_bgr():
    from fastdet.detector.detections import Detections
    from fastdet.viz.draw import draw_detections_inplace, draw_detections_yuv420

    grey = np.full((120, 160, 3), 90, np.uint8)
    detections = Detections(np.array([[20, 30, 80, 90], [100, 40, 150, 100]], np.int32),
                            np.array([1.5, 2.5], np.float32), np.array([1, 2]))
    drawn_bgr = draw_detections_inplace(grey.copy(), detections)
    i420 = cv2.cvtColor(grey, cv2.COLOR_BGR2YUV_I420)
    luma, chroma = i420[:120], i420[120:].reshape(2, 60, 80)
    draw_detections_yuv420(luma, chroma[0], chroma[1], detections)
    drawn_yuv = cv2.cvtColor(i420, cv2.COLOR_YUV2BGR_I420)
    # Below the labels (rows 40 on) only the boxes' lines change, the same pixels in both
    # but for a pixel of colour beside some lines: chroma has half the resolution.
    changed_bgr = np.abs(drawn_bgr[40:].astype(int) - grey[40:]).max(axis=2) > 40
    changed_yuv = np.abs(drawn_yuv[40:].astype(int) - grey[40:]).max(axis=2) > 40
    assert changed_bgr.sum() > 300
    assert (changed_bgr & changed_yuv).sum() > 0.9 * changed_bgr.sum()
    assert (changed_yuv & ~changed_bgr).sum() < 0.25 * changed_bgr.sum()
    for x, y in ((20, 60), (100, 70)):           # a point on each box's left edge
        assert np.abs(drawn_yuv[y, x].astype(int) - drawn_bgr[y, x]).max() < 40


@pytest.mark.parametrize("command", ["hog", "windows"])
def test_an_output_name_ending_in_a_slash_is_refused(model_path, frame_path, tmp_path, command):
    """``--out fig.png/`` names a folder; Path dropped the slash and the figure was
    written to the file ``fig.png``."""
    with pytest.raises(InputError, match="ends in a slash, so it names a folder"):
        run_viz([command, frame_path, "--model", model_path, "--out", f"{tmp_path}/fig.png/"])
    assert not (tmp_path / "fig.png").exists()


def test_bench_plot_name_ending_in_a_slash_is_refused(tmp_path, capsys):
    from fastdet.cli.app import EXIT_ERROR, main

    assert main(["bench", "--plot", f"{tmp_path}/scaling.png/"]) == EXIT_ERROR
    assert "ends in a slash, so it names a folder" in capsys.readouterr().err
