"""The per-video job without Dask: a whole video, its segments, their merge and drawing."""

import filecmp
import json

import av
import cv2
import numpy as np
import pytest
from batch_stubs import STUB_HEAT, STUB_THRESHOLD, two_blocks
from video_files import record_sources
from video_stubs import BlockDetector, bundled_model_path

from fastdet.batch.boundary import IdMap, compare
from fastdet.batch.job import process_one, render_one
from fastdet.batch.merge import concatenate_videos, merge_detections
from fastdet.batch.outputs import OutputPaths
from fastdet.batch.settings import make_settings
from fastdet.errors import InputError
from fastdet.video.pipeline import VideoPipeline
from fastdet.video.run import process_video
from fastdet.video.source import VideoSource


def outputs(folder, name, video=True, detections=True, thumbnail=False):
    return OutputPaths(folder / f"{name}.mp4" if video else None,
                       folder / f"{name}.jsonl" if detections else None,
                       folder / f"{name}.jpg" if thumbnail else None)


def test_a_whole_video_writes_what_fastdet_run_writes(data_dir, tmp_path):
    """The batch's job and `fastdet run`'s loop give the same detections, byte for byte."""
    from fastdet.detector.detector import Detector

    model = bundled_model_path()
    settings = make_settings(model=model)
    detector = Detector(model, threads=1)
    video = data_dir / "test_video.mp4"
    result = process_one(video, outputs(tmp_path, "job", thumbnail=True), settings,
                         detector=detector)
    process_video(video, None, VideoPipeline(detector, settings.track_config),
                  detections=tmp_path / "run.jsonl")
    assert filecmp.cmp(tmp_path / "job.jsonl", tmp_path / "run.jsonl", shallow=False)
    assert result["frames"] == 38 and result["fps"] == 25.0 and result["size"] == [1280, 720]
    assert len(result["track_ids"]) >= 1 and result["boxes"] >= 38
    assert result["start_state"] is None and result["end_state"] is None   # no boundaries
    assert cv2.imread(str(tmp_path / "job.jpg")).shape == (180, 320, 3)
    assert 0 < result["heat_floor"] < 1


def test_segments_merge_into_the_whole_video(blocks_video, tmp_path):
    settings = make_settings()
    whole = process_one(blocks_video, outputs(tmp_path, "whole", video=False), settings,
                        detector=BlockDetector())
    assert whole["frames"] == 90
    bounds, parts, maps = [(0, 40), (40, 75), (75, None)], [], []
    for k, (start, end) in enumerate(bounds):
        result = process_one(blocks_video, outputs(tmp_path, f"part{k}", video=False), settings,
                             (start, end), warmup_frames=start, detector=BlockDetector())
        parts.append((tmp_path / f"part{k}.jsonl", result))
    assert [p[1]["frames"] for p in parts] == [40, 35, 15]
    maps = [IdMap.identity()]
    for (_, before), (_, after) in zip(parts, parts[1:]):
        verdict = compare(before["end_state"], after["start_state"], STUB_THRESHOLD, STUB_HEAT)
        assert verdict.exact, verdict.reason
        maps.append(IdMap.across(*maps[-1].end_ids(before["end_state"]), after["start_state"]))
    for fmt in ("jsonl", "csv", "mot"):
        merge_detections([p for p, _ in parts], maps, tmp_path / f"merged.{fmt}", fmt)
        if fmt != "jsonl":
            process_one(blocks_video, outputs(tmp_path, f"whole-{fmt}", video=False), settings,
                        detector=BlockDetector(), detections_format=fmt)
    assert filecmp.cmp(tmp_path / "merged.jsonl", tmp_path / "whole.jsonl", shallow=False)
    assert filecmp.cmp(tmp_path / "merged.csv", tmp_path / "whole-csv.jsonl", shallow=False)
    assert filecmp.cmp(tmp_path / "merged.mot", tmp_path / "whole-mot.jsonl", shallow=False)

    # Each segment's boxes drawn in whole-video ids, the parts joined: the whole annotated video.
    for k, ((start, end), (part, _)) in enumerate(zip(bounds, parts)):
        assert render_one(blocks_video, (start, end), part, maps[k],
                          OutputPaths(tmp_path / f"part{k}.mp4", None, None)) == parts[k][1]["frames"]
    concatenate_videos([tmp_path / f"part{k}.mp4" for k in range(3)], tmp_path / "joined.mp4")
    process_one(blocks_video, outputs(tmp_path, "drawn", detections=False), settings,
                detector=BlockDetector())
    joined = list(VideoSource(tmp_path / "joined.mp4"))
    drawn = list(VideoSource(tmp_path / "drawn.mp4"))
    assert len(joined) == len(drawn) == 90
    # Encoded apart, the parts differ from the whole video by compression noise only
    # (H.264 at the default crf 23: about two grey levels on average).
    assert max(np.abs(a.astype(int) - b.astype(int)).mean() for a, b in zip(joined, drawn)) < 3.0
    with av.open(str(tmp_path / "joined.mp4")) as container:
        assert container.streams.video[0].frames == 90


@pytest.fixture(scope="module")
def blocks_video_b_frames(tmp_path_factory):
    """The same 90 frames in H.264 with B-frames, which frames not searched may skip."""
    path = tmp_path_factory.mktemp("job") / "blocks_b.mp4"
    with av.open(str(path), "w") as container:
        stream = container.add_stream("libx264", rate=10,
                                      options={"preset": "medium", "bf": "3", "g": "30"})
        stream.width, stream.height, stream.pix_fmt = 200, 120, "yuv420p"
        for frame in two_blocks(90):
            picture = av.VideoFrame.from_ndarray(frame, format="bgr24").reformat(format="yuv420p")
            container.mux(stream.encode(picture))
        container.mux(stream.encode(None))
    return path


def test_frames_left_undecoded_change_no_result(blocks_video_b_frames, tmp_path, monkeypatch):
    from fastdet.batch import job

    sources = record_sources(monkeypatch, job)
    settings = make_settings(every=3)
    video = blocks_video_b_frames
    whole = process_one(video, outputs(tmp_path, "whole", video=False), settings,
                        detector=BlockDetector())
    parts = [process_one(video, outputs(tmp_path, f"part{k}", video=False), settings,
                         (start, end), warmup_frames=start, detector=BlockDetector())
             for k, (start, end) in enumerate([(0, 45), (45, None)])]
    assert whole["frames"] == 90 and all(s.frames_left_undecoded > 0 for s in sources)
    verdict = compare(parts[0]["end_state"], parts[1]["start_state"], STUB_THRESHOLD, STUB_HEAT)
    assert verdict.exact, verdict.reason
    # Every frame decoded: the same detections, byte for byte.
    monkeypatch.setattr(job, "_needed_frames", lambda *args: None)
    process_one(video, outputs(tmp_path, "decoded", video=False), settings,
                detector=BlockDetector())
    assert sources[-1].frames_left_undecoded == 0
    assert filecmp.cmp(tmp_path / "whole.jsonl", tmp_path / "decoded.jsonl", shallow=False)
    assert "box" in (tmp_path / "whole.jsonl").read_text()


def test_a_segment_past_the_end_is_empty(blocks_video, tmp_path):
    result = process_one(blocks_video, outputs(tmp_path, "late", video=False), make_settings(),
                         (95, None), warmup_frames=10, detector=BlockDetector())
    assert result["frames"] == 0 and result["end_state"] is None
    result = process_one(blocks_video, outputs(tmp_path, "later", video=False), make_settings(),
                         (300, None), warmup_frames=10, detector=BlockDetector())
    assert result["frames"] == 0


def test_a_corrupt_video_fails_with_its_reason_and_writes_nothing(tmp_path):
    broken = tmp_path / "broken.mp4"
    broken.write_bytes(b"\x00\x00\x00\x18ftypmp42" + bytes(range(256)) * 8)
    with pytest.raises(InputError, match="cannot read .*broken.mp4 as a video"):
        process_one(broken, outputs(tmp_path, "out"), make_settings(), detector=BlockDetector())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["broken.mp4"]


def test_segment_detections_record_their_frames(blocks_video, tmp_path):
    process_one(blocks_video, outputs(tmp_path, "seg", video=False), make_settings(), (50, 60),
                warmup_frames=7, detector=BlockDetector())
    lines = (tmp_path / "seg.jsonl").read_text().splitlines()
    assert [json.loads(line)["frame"] for line in lines] == list(range(50, 60))
