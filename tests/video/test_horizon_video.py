"""An ``"auto"`` horizon in the video layer: one per video, from the file's start."""

import filecmp
from pathlib import Path

import av
import numpy as np
import pytest
from video_stubs import bundled_model_path

from fastdet.batch.job import process_one, warm_up
from fastdet.batch.outputs import OutputPaths
from fastdet.batch.settings import make_settings
from fastdet.batch.split_search import replays_from_hits
from fastdet.detector.config import DEFAULT_HORIZON, DetectorConfig
from fastdet.detector.detector import Detector
from fastdet.detector.horizon import DEFAULT_SNAP, FRAME_STEP, FRAMES
from fastdet.video.config import TrackConfig
from fastdet.video.horizon import horizon_frames, resolve_video_horizon
from fastdet.video.pipeline import VideoPipeline
from fastdet.video.run import process_video
from fastdet.video.source import VideoSource

AUTO = DetectorConfig.from_dict({"search": {"horizon": "auto"}})


@pytest.fixture()
def auto_config(tmp_path):
    path = tmp_path / "auto.toml"
    path.write_text('[search]\nhorizon = "auto"\n')
    return path


def test_a_file_is_read_from_its_start_whatever_the_run_starts_at(data_dir):
    video = data_dir / "test_video.mp4"
    with VideoSource(video) as whole, VideoSource(video, start=20) as late:
        frames, late_frames = horizon_frames(whole), horizon_frames(late)
        assert late.first_frame is not None      # the run's own source is not advanced
    assert len(frames) == min(FRAMES, -(-38 // FRAME_STEP))
    assert all(np.array_equal(a, b) for a, b in zip(frames, late_frames))
    with VideoSource(video) as source:
        expected = [frame for index, frame in enumerate(source) if index % FRAME_STEP == 0]
    assert all(np.array_equal(a, b) for a, b in zip(frames, expected))


def test_numeric_horizons_and_stand_in_detectors_are_left_alone(data_dir):
    detector = Detector(bundled_model_path(), threads=1)
    with VideoSource(data_dir / "test_video.mp4") as video:
        assert resolve_video_horizon(detector, video) is None
        assert resolve_video_horizon(object(), video) is None


@pytest.fixture(scope="module")
def pitched_video(data_dir, tmp_path_factory):
    """The test video as a camera pitched up by about 3 degrees would see it: 40 rows up."""
    path = tmp_path_factory.mktemp("pitched") / "pitched.mp4"
    with av.open(str(data_dir / "test_video.mp4")) as source, av.open(str(path), "w") as out:
        stream = source.streams.video[0]
        encoder = out.add_stream("libx264", rate=25)
        encoder.width, encoder.height, encoder.pix_fmt = stream.width, stream.height, "yuv420p"
        encoder.options = {"crf": "12", "preset": "veryfast"}
        for frame in source.decode(stream):
            image = frame.to_ndarray(format="bgr24")
            moved = np.zeros_like(image)
            moved[:-40] = image[40:]
            for packet in encoder.encode(av.VideoFrame.from_ndarray(moved, format="bgr24")):
                out.mux(packet)
        for packet in encoder.encode():
            out.mux(packet)
    return path


def test_a_run_searches_the_horizon_it_found(pitched_video, tmp_path, auto_config):
    lines = []
    stats = process_video(pitched_video, None, config=auto_config,
                          detections=tmp_path / "auto.jsonl", threads=1, log=lines.append)
    assert stats.horizon is not None and stats.horizon.frames == stats.horizon.frames_seen
    assert abs(stats.horizon.fraction - (416 - 40) / 720) < 0.015
    assert any("horizon at" in line for line in lines)
    numeric = AUTO.with_horizon(stats.horizon.fraction)
    detector = Detector(bundled_model_path(), numeric, threads=1)
    again = process_video(pitched_video, None, VideoPipeline(detector, TrackConfig()),
                          detections=tmp_path / "numeric.jsonl", threads=1)
    assert again.horizon is None
    assert filecmp.cmp(tmp_path / "auto.jsonl", tmp_path / "numeric.jsonl", shallow=False)
    # The default horizon, 40 rows too low for this camera, finds other boxes.
    process_video(pitched_video, None, detections=tmp_path / "default.jsonl", threads=1)
    assert not filecmp.cmp(tmp_path / "auto.jsonl", tmp_path / "default.jsonl", shallow=False)


def test_an_estimate_near_the_default_searches_the_default(data_dir, tmp_path, auto_config):
    video = data_dir / "test_video.mp4"
    stats = process_video(video, None, config=auto_config, detections=tmp_path / "auto.jsonl",
                          threads=1)
    assert 0 < abs(stats.horizon.fraction - DEFAULT_HORIZON) < DEFAULT_SNAP
    process_video(video, None, detections=tmp_path / "default.jsonl", threads=1)
    assert filecmp.cmp(tmp_path / "auto.jsonl", tmp_path / "default.jsonl", shallow=False)


def test_batch_segments_resolve_the_whole_videos_horizon(pitched_video, tmp_path, auto_config):
    settings = make_settings(model=bundled_model_path(), config=auto_config)
    assert not replays_from_hits(settings)    # segments warm up instead
    detector = Detector(bundled_model_path(), settings.detector_config, threads=1)
    warm_up(detector, settings.track_config,
            np.zeros((720, 1280, 3), np.uint8))   # noise shows none: the default meanwhile
    assert detector.config.search.horizon == DEFAULT_HORIZON
    horizons = []
    for name, frame_range in (("whole", None), ("late", (20, None))):
        process_one(pitched_video, OutputPaths(None, tmp_path / f"{name}.jsonl", None),
                    settings, frame_range, warmup_frames=5, detector=detector)
        horizons.append(detector.config.search.horizon)
    assert horizons[0] == horizons[1] and abs(horizons[0] - 376 / 720) < 0.015
    assert detector.auto_horizon


def test_eval_and_detect_print_the_horizon(data_dir, auto_config, capsys):
    from fastdet.cli import main

    video = data_dir / "test_video.mp4"
    annotations = str(Path(__file__).parents[1] / "data" / "test_video_annotations.json")
    assert main(["eval", annotations, str(video), "--config", str(auto_config),
                 "--threads", "1"]) == 0
    assert "horizon at" in capsys.readouterr().err
    images = sorted(str(p) for p in (data_dir / "test_images").glob("*.jpg"))
    assert main(["detect", *images, "--config", str(auto_config), "--threads", "1"]) == 0
    captured = capsys.readouterr()
    assert f"{len(images)} image(s): horizon at" in captured.err and "searching at" in captured.err
    assert len(captured.out.splitlines()) == len(images)
    assert main(["detect", *images[:1], "--threads", "1"]) == 0
    assert "horizon" not in capsys.readouterr().err


class _LiveSource:
    """What horizon_frames reads of a live source: its kind and first frame."""

    kind = "network"
    name = "udp://127.0.0.1:1234"

    def __init__(self, first_frame):
        self.first_frame = first_frame


def test_a_live_source_gives_its_first_frame(data_dir):
    from road_images import road

    live = _LiveSource(road(1280, 720, 0.5))
    assert len(horizon_frames(live)) == 1
    detector = Detector(bundled_model_path(), AUTO, threads=1)
    lines = []
    estimate = resolve_video_horizon(detector, live, lines.append)
    assert abs(estimate.fraction - 0.5) < 0.01
    assert detector.config.search.horizon == estimate.fraction
    assert lines and lines[0].startswith("udp://127.0.0.1:1234: horizon at 0.5")
    assert horizon_frames(_LiveSource(None)) == []


def test_the_horizon_option_overrides_the_config(pitched_video, tmp_path, auto_config, capsys):
    from fastdet.cli import main

    assert main(["run", str(pitched_video), "--horizon", "auto", "--threads", "1", "--quiet",
                 "--detections", str(tmp_path / "option.jsonl")]) == 0
    process_video(pitched_video, None, config=auto_config, detections=tmp_path / "config.jsonl",
                  threads=1)
    assert filecmp.cmp(tmp_path / "option.jsonl", tmp_path / "config.jsonl", shallow=False)
    # A number overrides an "auto" config.
    assert main(["run", str(pitched_video), "--config", str(auto_config), "--horizon", "0.58",
                 "--threads", "1", "--detections", str(tmp_path / "fixed.jsonl")]) == 0
    assert "horizon at" not in capsys.readouterr().err
    process_video(pitched_video, None, detections=tmp_path / "default.jsonl", threads=1)
    assert filecmp.cmp(tmp_path / "fixed.jsonl", tmp_path / "default.jsonl", shallow=False)
    settings = make_settings(model=bundled_model_path(), horizon="auto")
    assert settings.detector_config.search.auto_horizon
    with pytest.raises(SystemExit) as stop:
        main(["detect", str(pitched_video), "--horizon", "up"])
    assert stop.value.code == 2
    assert "--horizon: expected a fraction of the frame height or auto" in capsys.readouterr().err


def test_a_files_estimate_is_made_once_until_the_file_changes(pitched_video, tmp_path,
                                                               monkeypatch):
    """A batch worker runs a video's segments in turn: they read its frames once."""
    import os
    import shutil

    from fastdet.video import horizon as video_horizon_module

    copy = tmp_path / "copy.mp4"
    shutil.copy(pitched_video, copy)
    reads = []
    real = video_horizon_module.horizon_frames
    monkeypatch.setattr(video_horizon_module, "horizon_frames",
                        lambda video: reads.append(video.name) or real(video))
    detector = Detector(bundled_model_path(), AUTO, threads=1)
    found = []
    for start in (0, 20, 0):
        with VideoSource(copy, start=start) as video:
            found.append(resolve_video_horizon(detector, video))
    assert len(reads) == 1 and found[0] == found[1] == found[2]
    stat = os.stat(copy)
    os.utime(copy, ns=(stat.st_atime_ns, stat.st_mtime_ns + 10**9))
    with VideoSource(copy) as video:
        assert resolve_video_horizon(detector, video) == found[0]
    assert len(reads) == 2
    # A numeric horizon takes no estimate.
    numeric = Detector(bundled_model_path(), threads=1)
    numeric.take_horizon(found[0])
    assert numeric.config.search.horizon == DEFAULT_HORIZON
