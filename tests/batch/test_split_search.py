"""Segments searched apart and replayed in one pass give the whole-video run's detections."""

import filecmp

import numpy as np
import pytest
from video_stubs import BlockDetector, bundled_model_path

from fastdet.batch.job import process_one
from fastdet.batch.outputs import OutputPaths
from fastdet.batch.settings import make_settings
from fastdet.batch.split_search import replay_segments, replays_from_hits, search_segment
from fastdet.errors import InputError


def _whole(video, settings, detector, target):
    return process_one(video, OutputPaths(None, target, None), settings, detector=detector)


def _split(video, bounds, settings, detector, folder, whole=None):
    hits, parts = [], []
    for k, frame_range in enumerate(bounds):
        hits.append(folder / f"segment{k}.hits.npz")
        parts.append(folder / f"segment{k}.jsonl")
        search_segment(video, frame_range, hits[-1], settings, detector=detector)
    return replay_segments(hits, parts, settings, detector=detector, whole=whole), parts


def _joined(parts, target):
    target.write_bytes(b"".join(part.read_bytes() for part in parts))
    return target


def no_snapping(tmp_path, **options):
    """Settings whose temporal steps read no pixels (replays_from_hits)."""
    config = tmp_path / "no-snap.toml"
    config.write_text("[boxes]\nsnap_sides = 0.0\n")
    return make_settings(config=config, **options)


@pytest.mark.parametrize("every", [1, 3])
def test_the_test_video_in_segments_equals_the_whole_run(data_dir, every, tmp_path):
    from fastdet.detector.detector import Detector

    settings = no_snapping(tmp_path, model=bundled_model_path(), every=every)
    assert replays_from_hits(settings)
    detector = Detector(bundled_model_path(), settings.detector_config, threads=1)
    video = data_dir / "test_video.mp4"
    whole = _whole(video, settings, detector, tmp_path / "whole.jsonl")
    # Boundaries off the search schedule, and one segment of a single frame.
    results, parts = _split(video, [(0, 13), (13, 14), (14, 29), (29, None)], settings, detector,
                            tmp_path)
    assert [r["frames"] for r in results] == [13, 1, 15, 9]
    assert filecmp.cmp(_joined(parts, tmp_path / "joined.jsonl"), tmp_path / "whole.jsonl",
                       shallow=False)
    assert sum(r["boxes"] for r in results) == whole["boxes"] > 0
    assert sorted(set().union(*(r["track_ids"] for r in results))) == whole["track_ids"]


@pytest.mark.parametrize("fmt", ["jsonl", "csv", "mot"])
def test_stub_detector_segments_equal_the_whole_run(blocks_video, fmt, tmp_path):
    settings = no_snapping(tmp_path, format=fmt)
    _whole(blocks_video, settings, BlockDetector(), tmp_path / "whole.out")
    results, parts = _split(blocks_video, [(0, 40), (40, 75), (75, None)], settings,
                            BlockDetector(), tmp_path, whole=tmp_path / "replayed.out")
    assert [r["frames"] for r in results] == [40, 35, 15]
    # The video's file in its format, and the jsonl parts the boxes are drawn from.
    assert filecmp.cmp(tmp_path / "replayed.out", tmp_path / "whole.out", shallow=False)
    if fmt == "jsonl":
        assert filecmp.cmp(_joined(parts, tmp_path / "joined.jsonl"), tmp_path / "whole.out",
                           shallow=False)


def test_a_searched_frame_without_hits_is_an_error(blocks_video, tmp_path):
    settings = no_snapping(tmp_path)
    search_segment(blocks_video, (0, 10), tmp_path / "a.npz", settings, detector=BlockDetector())
    with np.load(tmp_path / "a.npz") as part:
        data = {name: part[name] for name in part.files}
    data["index"], data["counts"], data["windows"] = (data[name][:-1] for name in
                                                      ("index", "counts", "windows"))
    np.savez(tmp_path / "b.npz", **data)
    with pytest.raises(InputError, match="frame 9 is searched but has no hits"):
        replay_segments([tmp_path / "b.npz"], [tmp_path / "b.jsonl"], settings,
                        detector=BlockDetector())


def test_segments_must_follow_each_other(blocks_video, tmp_path):
    settings = no_snapping(tmp_path)
    for name, frame_range in (("a", (0, 10)), ("b", (12, 20))):
        search_segment(blocks_video, frame_range, tmp_path / f"{name}.npz", settings,
                       detector=BlockDetector())
    with pytest.raises(InputError, match="starts at frame 12, not 10"):
        replay_segments([tmp_path / "a.npz", tmp_path / "b.npz"],
                        [tmp_path / "a.jsonl", tmp_path / "b.jsonl"], settings,
                        detector=BlockDetector())


def test_patch_tracking_is_refused(blocks_video, tmp_path):
    with pytest.raises(ValueError, match="warm up"):
        search_segment(blocks_video, (0, 10), tmp_path / "a.npz", make_settings(track=True),
                       detector=BlockDetector())


def test_settings_whose_temporal_steps_read_pixels_are_not_replayed(tmp_path):
    from fastdet.detector.detector import Detector

    snapping = make_settings(model=bundled_model_path())    # the default snaps box sides
    tracking = make_settings(model=bundled_model_path(), track=True, config=None)
    assert not replays_from_hits(snapping) and not replays_from_hits(tracking)
    for settings in (snapping, tracking):
        with pytest.raises(ValueError, match="cannot be replayed from hits"):
            replay_segments([], [], settings, detector=Detector(threads=1))

