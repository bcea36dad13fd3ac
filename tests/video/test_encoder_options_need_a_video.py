"""``--codec``, ``--crf`` and ``--preset`` without a video output are refused, never ignored."""

from __future__ import annotations

import pytest
from video_files import write_clip

from fastdet.cli import app as cli
from fastdet.errors import InputError
from fastdet.video.run import process_video


@pytest.mark.parametrize("options, named", [
    (["--crf", "-1"], "--crf applies"),
    (["--crf", "20"], "--crf applies"),                       # a good value decides nothing too
    (["--codec", "hevc", "--preset", "bogus"], "--codec and --preset apply"),
    (["--codec", "h264"], "--codec applies")])
def test_run_refuses_encoder_options_without_a_video(tmp_path, capsys, options, named):
    detections = tmp_path / "d.jsonl"
    code = cli.main(["run", str(tmp_path / "never-opened.mp4"), "--detections", str(detections),
                     *options])
    err = capsys.readouterr().err
    assert code == 2 and not detections.exists()
    assert err.startswith(f"fastdet: error: {named} only to the annotated video")
    assert err.count("\n") == 1


def test_process_video_refuses_them_without_a_target(tmp_path):
    clip = write_clip(tmp_path / "clip.mp4", 2)
    with pytest.raises(InputError, match="--preset applies only to the annotated video"):
        process_video(clip, detections=tmp_path / "d.jsonl", preset="slow")
    assert not (tmp_path / "d.jsonl").exists()
