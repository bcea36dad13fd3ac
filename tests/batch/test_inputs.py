"""What a batch takes for its videos, and where their outputs go."""

import os
from pathlib import Path

import pytest

from fastdet.batch.inputs import find_videos
from fastdet.batch.outputs import OutputPaths, output_paths, remove_leftovers
from fastdet.batch.settings import make_settings
from fastdet.errors import InputError


def touch(path):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"not decoded here")
    return path


@pytest.fixture
def footage(tmp_path):
    root = tmp_path / "footage"
    for name in ("b.mp4", "a.MOV", "day1/c.mkv", "day1/deeper/d.avi", "notes.txt", ".hidden.mp4",
                 ".cache/e.mp4", "day1/f.jpg"):
        touch(root / name)
    return root


def test_a_folder_is_searched_recursively_for_videos(footage):
    videos = find_videos([footage])
    assert [v.relative for v in videos] == ["a.MOV", "b.mp4", "day1/c.mkv", "day1/deeper/d.avi"]
    assert all(v.path.is_absolute() and v.path.is_file() for v in videos)
    assert videos[2].key == "day1/c"


def test_a_video_keeps_its_name_and_is_taken_once(footage):
    videos = find_videos([footage / "day1" / "c.mkv", footage, footage / "b.mp4"])
    assert [v.relative for v in videos][:2] == ["c.mkv", "a.MOV"]
    assert len(videos) == 4


def test_the_output_folder_is_not_searched(footage):
    touch(footage / "out" / "b.mp4")
    assert "out/b.mp4" not in [v.relative for v in find_videos([footage], exclude=footage / "out")]
    assert "out/b.mp4" in [v.relative for v in find_videos([footage])]


def test_a_list_file_names_videos_and_folders(footage, tmp_path):
    listing = tmp_path / "videos.txt"
    listing.write_text(f"# dashcam\n\nfootage/b.mp4\n  footage/day1/deeper/d.avi  \n"
                       f"{footage / 'a.MOV'}\nfootage/day1\n../{tmp_path.name}/footage/b.mp4\n")
    videos = find_videos([listing])
    assert [v.relative for v in videos] == ["footage/b.mp4", "footage/day1/deeper/d.avi",
                                            "a.MOV", "c.mkv"]


def test_a_listed_file_is_a_video_whatever_its_suffix(tmp_path):
    touch(tmp_path / "clip.dashcam")
    (tmp_path / "list.txt").write_text("clip.dashcam\n")
    assert [v.relative for v in find_videos([tmp_path / "list.txt"])] == ["clip.dashcam"]


@pytest.mark.parametrize("content, message", [
    ("missing.mp4\n", "input not found: .*missing.mp4 \\(listed in .*list.txt\\)"),
    ("", "no videos found"),
])
def test_list_errors(tmp_path, content, message):
    (tmp_path / "list.txt").write_text(content)
    with pytest.raises(InputError, match=message):
        find_videos([tmp_path / "list.txt"])


def test_errors_name_the_problem(tmp_path, footage):
    with pytest.raises(InputError, match="input not found"):
        find_videos([tmp_path / "nothing"])
    (tmp_path / "binary.dat").write_bytes(b"\xff\xfe\x00\x81")
    with pytest.raises(InputError, match="neither a video .* nor a text file"):
        find_videos([tmp_path / "binary.dat"])
    touch(tmp_path / "other" / "b.mp4")
    with pytest.raises(InputError, match="would write the same outputs"):
        find_videos([footage, tmp_path / "other"])
    touch(footage / "b.mkv")
    with pytest.raises(InputError, match="would write the same outputs \\(b\\.\\*\\)"):
        find_videos([footage])


def test_files_that_are_no_regular_files_are_not_videos(footage, tmp_path):
    """A FIFO named like a video: hashing it for the manifest waited for a writer
    for good.  In a folder it is left out (a dangling link is still taken, and
    fails alone as an unreadable video); named or listed, it is a one-line error."""
    os.mkfifo(footage / "pipe.mp4")
    (footage / "gone.mp4").symlink_to(tmp_path / "nowhere.mp4")
    relatives = [v.relative for v in find_videos([footage])]
    assert "pipe.mp4" not in relatives and "gone.mp4" in relatives
    with pytest.raises(InputError, match="pipe.mp4 is not a regular file"):
        find_videos([footage / "pipe.mp4"])
    (tmp_path / "list.txt").write_text("footage/pipe.mp4\n")
    with pytest.raises(InputError, match="pipe.mp4 \\(listed in .*list.txt\\) is not a regular"):
        find_videos([tmp_path / "list.txt"])
    os.mkfifo(tmp_path / "list.fifo")
    with pytest.raises(InputError, match="list.fifo is not a regular file"):
        find_videos([tmp_path / "list.fifo"])


def test_outputs_mirror_the_relative_path(footage, tmp_path):
    video = find_videos([footage])[2]
    out = tmp_path / "out"
    paths = output_paths(video, out, make_settings())
    assert paths == OutputPaths(out / "day1/c.mp4", out / "day1/c.jsonl", out / "day1/c.jpg")
    assert paths.relative_to(out) == {"video": "day1/c.mp4", "detections": "day1/c.jsonl",
                                      "thumbnail": "day1/c.jpg"}
    only = output_paths(video, out, make_settings(video=False, format="mot"))
    assert only == OutputPaths(None, out / "day1/c.txt", None)


def test_an_output_may_not_overwrite_its_input(footage):
    video = find_videos([footage])[1]          # b.mp4
    with pytest.raises(InputError, match="would overwrite the input video"):
        output_paths(video, footage, make_settings())


def test_leftovers_of_killed_attempts_are_removed(tmp_path):
    paths = OutputPaths(tmp_path / "c.mp4", tmp_path / "c.jsonl", None)
    for name in (".c.x1y2.part.mp4", ".c.abc.part.jsonl", "c.mp4", ".d.x.part.mp4"):
        touch(tmp_path / name)
    parts = tmp_path / ".fastdet-parts" / "day1" / "c"
    touch(parts / "segment-0000.jsonl")
    remove_leftovers(paths, parts)
    assert sorted(p.name for p in tmp_path.iterdir()) == [".d.x.part.mp4", "c.mp4"]


def test_settings_are_checked_and_hashed(tmp_path):
    base = make_settings()
    assert base.config_sha256 == make_settings().config_sha256
    assert make_settings(every=5).config_sha256 != base.config_sha256
    assert make_settings(format="csv").config_sha256 != base.config_sha256
    assert make_settings(threads=2).config_sha256 == base.config_sha256   # same outputs
    mp4v = make_settings(codec="mp4v", crf=4)
    assert mp4v.encoder == ("mp4v", 4, None) and mp4v.config_sha256 != base.config_sha256
    assert make_settings(crf=30).config_sha256 != base.config_sha256
    assert make_settings(codec="h264").config_sha256 == base.config_sha256
    assert make_settings(crf=23, preset="ultrafast").config_sha256 == base.config_sha256
    # Without a video the encoder would decide nothing: giving one is refused, as by run.
    with pytest.raises(InputError, match="--codec and --preset apply only to the annotated video"):
        make_settings(video=False, codec="mp4v", preset="fast")
    with pytest.raises(InputError, match="--crf applies only"):
        make_settings(video=False, crf=-1)
    for options, message in (({"preset": "warp-speed"}, "h264 has no preset 'warp-speed'"),
                             ({"codec": "vp9", "preset": "99"}, "the vp9 encoder refuses"),
                             ({"crf": 52}, "must be 0-51"),
                             ({"codec": "mp4v", "preset": "fast"}, "does not apply to mp4v"),
                             ({"crf": "high"}, "--crf must be a whole number")):
        with pytest.raises(InputError, match=message):
            make_settings(**options)
    assert len(base.model_sha256) == 64 and base.model_bytes[:2] == b"PK"
    with pytest.raises(InputError, match="nothing to write"):
        make_settings(video=False, detections=False)
    with pytest.raises(InputError, match="--every"):
        make_settings(every=0)
    bad = tmp_path / "model.npz"
    bad.write_bytes(b"junk")
    with pytest.raises(Exception, match="model"):
        make_settings(model=bad)
    assert Path(bad).exists()


def test_a_fractional_every_is_refused_for_what_it_is():
    with pytest.raises(InputError, match=r"--every must be a whole number >= 1, got 2\.5"):
        make_settings(every=2.5)


def test_a_bad_segment_is_refused_before_a_cluster_starts(tmp_path, monkeypatch):
    """fastdet.batch(segment="abc") was refused once the local cluster had started."""
    import fastdet.batch as batch_module

    def no_cluster(*args, **kwargs):
        raise AssertionError("a cluster was started")

    monkeypatch.setattr(batch_module, "batch_client", no_cluster)
    monkeypatch.setattr(batch_module, "compile_for_local_workers", no_cluster)
    video = tmp_path / "a.mp4"
    video.write_bytes(b"")
    with pytest.raises(InputError, match="--segment takes frames"):
        batch_module.run_batch([video], tmp_path / "out", segment="abc")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("call", [
    lambda batch, video, out: batch([video], out, bogus=1),
    lambda batch, video, out: batch(inputs=[video], out_dir=out, every=2, trak=True),
])
def test_an_unknown_option_is_named_against_batch_itself(tmp_path, monkeypatch, call):
    """fastdet.batch(bogus=1) said make_settings() had no such argument."""
    import fastdet
    import fastdet.batch as batch_module

    def no_cluster(*args, **kwargs):
        raise AssertionError("a cluster was started")

    monkeypatch.setattr(batch_module, "batch_client", no_cluster)
    video = tmp_path / "a.mp4"
    video.write_bytes(b"")
    unexpected = r"^batch\(\) got an unexpected keyword argument '(bogus|trak)'$"
    with pytest.raises(TypeError, match=unexpected):
        call(fastdet.batch, video, tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_the_package_called_without_its_arguments_names_batch():
    import fastdet

    with pytest.raises(TypeError, match=r"^batch\(\) missing 2 required positional"):
        fastdet.batch()


def test_a_list_may_name_files_that_are_not_utf8(tmp_path):
    """`find > list.txt` over a folder holding a name that is not UTF-8: the list was
    refused as "neither a video nor a text file", though such a video named directly
    or found in a folder is taken."""
    odd = touch(Path(os.fsdecode(bytes(tmp_path) + b"/caf\xe9.mp4")))
    touch(tmp_path / "b.mp4")
    (tmp_path / "list.txt").write_bytes(b"caf\xe9.mp4\r\nb.mp4\r\n")
    videos = find_videos([tmp_path / "list.txt"])
    assert [v.path for v in videos] == [odd, tmp_path / "b.mp4"]
    assert [os.fsencode(v.relative) for v in videos] == [b"caf\xe9.mp4", b"b.mp4"]


def test_a_missing_listed_name_that_is_not_utf8_shows_its_bytes(tmp_path):
    (tmp_path / "list.txt").write_bytes(b"caf\xe9.mp4\n")
    with pytest.raises(InputError, match=r"input not found: .*caf\\xe9\.mp4 \(listed in"):
        find_videos([tmp_path / "list.txt"])


def test_a_byte_order_mark_is_no_part_of_the_first_name(tmp_path):
    """Notepad's UTF-8 starts with EF BB BF: 'input not found: \\ufeffa.mp4'."""
    touch(tmp_path / "a.mp4")
    (tmp_path / "list.txt").write_bytes(b"\xef\xbb\xbfa.mp4\n")
    assert [v.relative for v in find_videos([tmp_path / "list.txt"])] == ["a.mp4"]


@pytest.mark.parametrize("threads", [0, 257, 100000])
def test_threads_per_task_are_bounded_as_fastdet_run_bounds_them(threads):
    """100000 ended in MemoryError tracebacks."""
    with pytest.raises(InputError, match=rf"^--threads must be 1-256, got {threads}$"):
        make_settings(threads=threads)
