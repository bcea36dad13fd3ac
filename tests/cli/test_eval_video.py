"""``fastdet eval`` on an annotated video: detection and tracking metrics, modes, errors."""

from __future__ import annotations

import json

import cv2
import pytest
from video_stubs import BlockDetector, moving_block

from fastdet.cli import eval as commands_eval
from fastdet.cli.app import EXIT_ERROR, main
from fastdet.video.config import TrackConfig
from fastdet.video.pipeline import VideoPipeline

FRAMES = 12


@pytest.fixture(scope="module")
def block_video(tmp_path_factory):
    """A 12-frame mp4 of one textured block moving right, and its annotation file."""
    folder = tmp_path_factory.mktemp("blocks")
    path = folder / "blocks.mp4"
    frames, truth = moving_block(FRAMES)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 10.0, (200, 120))
    for frame in frames:
        writer.write(frame)
    writer.release()
    images = {f"frame{i:04d}": [{"box": list(box), "id": 1}] for i, box in enumerate(truth)}
    annotations = folder / "blocks.json"
    annotations.write_text(json.dumps({
        "images": images,
        "frames": {"development": [f"frame{i:04d}" for i in range(6)],
                   "held_out": [f"frame{i:04d}" for i in range(8, FRAMES)]}}))
    return path, annotations


@pytest.fixture
def stub_pipeline(monkeypatch):
    """``eval`` with the block-finding stub detector instead of a model."""
    built = []

    def build(args):
        config = TrackConfig(every=args.every, tracking=args.track, heat_smoothing="none")
        built.append(config)
        return VideoPipeline(BlockDetector(), config)
    monkeypatch.setattr(commands_eval, "make_pipeline", build)
    return built


def run_json(capsys, *argv):
    assert main(["eval", *map(str, argv), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_a_video_gives_detection_and_tracking_figures(stub_pipeline, block_video, capsys):
    video, annotations = block_video
    report = run_json(capsys, annotations, video)
    assert (report["precision"], report["recall"], report["ap"]) == (1.0, 1.0, 1.0)
    # mp4 compression blurs the block's edges by a pixel.
    assert 0.9 <= report["iou_p10"] <= report["mean_iou"] <= 1.0
    tracking = report["tracking"]
    assert (tracking["mota"], tracking["idf1"], tracking["id_switches"]) == (1.0, 1.0, 0)
    assert (tracking["objects"], tracking["vehicles"], tracking["frames"]) == (FRAMES, 1, FRAMES)


def test_every_n_reuses_boxes_and_loses_overlap(stub_pipeline, block_video, capsys):
    video, annotations = block_video
    every_frame = run_json(capsys, annotations, video)
    report = run_json(capsys, annotations, video, "--every", 5)
    assert stub_pipeline[-1].every == 5
    # The block moves 4 px a frame: boxes reused for up to 4 frames still
    # overlap it, but less.
    assert report["mean_iou"] < every_frame["mean_iou"] - 0.05
    assert report["tracking"]["id_switches"] == 0
    run_json(capsys, annotations, video, "--track")
    assert stub_pipeline[-1].tracking


def test_a_split_scores_only_its_frames(stub_pipeline, block_video, capsys):
    video, annotations = block_video
    report = run_json(capsys, annotations, video, "--split", "held_out")
    assert report["n_gt"] == FRAMES - 8
    assert sorted(report["images"]) == [f"frame{i:04d}" for i in range(8, FRAMES)]
    assert report["tracking"]["frames"] == FRAMES - 8


def test_the_human_readable_report(stub_pipeline, block_video, capsys):
    video, annotations = block_video
    assert main(["eval", str(annotations), str(video)]) == 0
    out = capsys.readouterr().out
    assert "IoU 10th percentile 0.9" in out
    assert "MOTA 1.000  IDF1 1.000  ID switches 0" in out


def expect_error(capsys, argv, words):
    assert main(["eval", *map(str, argv)]) == EXIT_ERROR
    err = capsys.readouterr().err.strip()
    assert err.startswith("fastdet: error: ") and "\n" not in err and words in err, err


def test_errors(stub_pipeline, block_video, capsys, tmp_path, data_dir):
    video, annotations = block_video
    expect_error(capsys, [annotations, video, "--split", "test"],
                 f"no split 'test' in {annotations}")
    expect_error(capsys, [annotations, tmp_path / "none.mp4"], "no such folder or video")
    images = data_dir / "test_images"
    expect_error(capsys, [images / "annotations.json", images, "--every", "5"],
                 "apply to a video")
    names = tmp_path / "names.json"
    names.write_text(json.dumps({"images": {"test1.jpg": []}}))
    expect_error(capsys, [names, video], "frame<N>")
    late = tmp_path / "late.json"
    late.write_text(json.dumps({"images": {"frame0500": []}}))
    expect_error(capsys, [late, video], "ends before its annotated frame frame0500")


def test_annotations_without_ids_give_detection_figures_only(stub_pipeline, block_video,
                                                             capsys, tmp_path):
    video, _ = block_video
    _, truth = moving_block(FRAMES)
    plain = tmp_path / "plain.json"
    plain.write_text(json.dumps({"images": {f"frame{i}": [{"box": list(b)}]
                                            for i, b in enumerate(truth)}}))
    report = run_json(capsys, plain, video)
    assert report["recall"] == 1.0 and "tracking" not in report


def test_ids_on_only_some_vehicles_are_refused(stub_pipeline, block_video, capsys, tmp_path):
    """Vehicles with and without ids silently dropped MOTA, IDF1 and the rest."""
    video, _ = block_video
    _, truth = moving_block(FRAMES)
    images = {f"frame{i}": [{"box": list(b), "id": 1}] for i, b in enumerate(truth)}
    del images["frame7"][0]["id"], images["frame10"][0]["id"]
    partial = tmp_path / "partial.json"
    partial.write_text(json.dumps({"images": images,
                                   "frames": {"late": [f"frame{i}" for i in range(6, FRAMES)]}}))
    expect_error(capsys, [partial, video],
                 f"{partial}: 10 of 12 vehicles that are not difficult have an \"id\" and "
                 f"images['frame7'][0] has none")
    expect_error(capsys, [partial, video, "--split", "late"],
                 "4 of 6 vehicles of split 'late' that are not difficult have an \"id\" and "
                 "images['frame7'][0] has none")
    # Ids only on difficult vehicles: as much a mistake.
    for name, objects in images.items():
        objects[0].pop("id", None)
        objects.append({"box": [0, 0, 10, 10], "difficult": True, "id": 2})
    partial.write_text(json.dumps({"images": images}))
    expect_error(capsys, [partial, video], "0 of 12 vehicles that are not difficult")


def test_difficult_vehicles_may_go_without_an_id(stub_pipeline, block_video, capsys, tmp_path):
    video, _ = block_video
    _, truth = moving_block(FRAMES)
    images = {f"frame{i}": [{"box": list(b), "id": 1}, {"box": [0, 0, 10, 10], "difficult": True}]
              for i, b in enumerate(truth)}
    annotations = tmp_path / "difficult.json"
    annotations.write_text(json.dumps({"images": images}))
    tracking = run_json(capsys, annotations, video)["tracking"]
    assert (tracking["mota"], tracking["vehicles"], tracking["objects"]) == (1.0, 1, FRAMES)


def test_the_bundled_model_tracks_both_cars_of_the_test_video(capsys, data_dir):
    """The real pipeline on the real clip: the two near cars, no switch, nothing else."""
    from pathlib import Path

    annotations = Path(__file__).parents[1] / "data" / "test_video_annotations.json"
    report = run_json(capsys, annotations, data_dir / "test_video.mp4", "--threads", 1)
    assert (report["precision"], report["recall"]) == (1.0, 1.0)
    tracking = report["tracking"]
    assert (tracking["mota"], tracking["idf1"], tracking["id_switches"]) == (1.0, 1.0, 0)
