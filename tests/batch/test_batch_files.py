"""The output folder's own files (manifest, report, lock), odd file names, and re-runs
that change which outputs a video gets.

The batches here run on a local cluster of one worker (``fastdet batch
--workers 1``) over one-frame clips.
"""

from __future__ import annotations

import fcntl
import json
import os
import shutil
from pathlib import Path

import pytest
from video_files import write_clip

from fastdet.batch import runner
from fastdet.batch.inputs import display_name, find_videos
from fastdet.batch.outputs import LOCK_NAME, check_outputs, remove_replaced
from fastdet.batch.report import summary_table, write_report
from fastdet.batch.settings import make_settings
from fastdet.cli.app import main
from fastdet.errors import InputError
from fastdet.files.strict_json import restore_names

#: ``v\xff.mp4``: a file name that is not UTF-8, as Python sees it (surrogateescape).
ODD_NAME = os.fsdecode(b"v\xff.mp4")


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    return write_clip(tmp_path_factory.mktemp("clip") / "clip.mp4", 2)


def manifest_records(out):
    """The manifest's records, each line parsed as strict JSON (RFC 8259: no NaN, no lone
    surrogate), with the names that are not UTF-8 put back from their ``_bytes`` fields."""
    raw = (out / "manifest.jsonl").read_bytes()
    records = []
    for line in raw.decode("utf-8").splitlines():
        record = json.loads(line, parse_constant=_not_json)
        line.encode("utf-8")
        json.dumps(record, ensure_ascii=False).encode("utf-8")   # a "\udcff" escape fails
        records.append(restore_names(record))
    return {r["relative"]: r for r in records}


def _not_json(constant):
    raise ValueError(f"{constant} is not JSON")


@pytest.mark.parametrize("name, options", [("manifest.mp4", []), ("sub/manifest.mp4", []),
                                           (".fastdet-parts/a.mp4", ["--format", "csv"])])
def test_an_output_named_like_the_batchs_own_files_is_refused_before_any_work(
        clip, tmp_path, capsys, name, options):
    """manifest.mp4's detections went to DIR/manifest.jsonl, the manifest itself: the
    batch exited 0 with the detections lost, and a re-run skipped the video as done."""
    footage = tmp_path / "footage"
    (footage / name).parent.mkdir(parents=True)
    shutil.copy(clip, footage / name)
    shutil.copy(clip, footage / "other.mp4")
    listing = footage / "list.txt"          # a list names hidden files too
    listing.write_text(f"{name}\nother.mp4\n")
    out = tmp_path / "out"
    code = main(["batch", str(listing), "--out-dir", str(out), "--workers", "1", "-q", *options])
    error = capsys.readouterr().err
    if name == "sub/manifest.mp4":          # sub/manifest.jsonl is no batch file: taken
        assert code == 0, error
        assert "sub/manifest.jsonl" in {o for r in manifest_records(out).values()
                                        for o in r["outputs"].values()}
        return
    assert code == 2
    assert error.count("\n") == 1 and error.startswith("fastdet: error: ")
    assert f"footage/{name} would write" in error and "the batch's" in error
    assert not out.exists()                 # refused before the folder or a cluster


def test_the_check_names_the_clash_for_the_settings_asked_for(tmp_path):
    (tmp_path / "manifest.mp4").write_bytes(b"not decoded here")
    videos = find_videos([tmp_path / "manifest.mp4"])
    with pytest.raises(InputError, match="manifest.jsonl, the batch's manifest: rename"):
        check_outputs(videos, tmp_path / "out", make_settings())
    check_outputs(videos, tmp_path / "out", make_settings(format="csv"))   # manifest.csv


def test_a_name_that_is_not_utf8_is_processed_with_the_others(clip, tmp_path, capsys):
    """One such name sent Dask's messages (msgpack) a surrogate: the batch died with exit
    70, the healthy video recorded as failed (scheduler-connection-lost)."""
    footage = tmp_path / "footage"
    footage.mkdir()
    shutil.copy(clip, footage / "good.mp4")
    shutil.copy(clip, footage / ODD_NAME)
    out = tmp_path / "out"
    code = main(["batch", str(footage), "--out-dir", str(out), "--workers", "1", "-q"])
    printed = capsys.readouterr()
    assert code == 0, printed.err
    assert "v\\xff.mp4  done" in printed.out and "2 videos: 2 done" in printed.out
    records = manifest_records(out)              # strict UTF-8 JSON, the name's bytes kept
    line = next(line for line in (out / "manifest.jsonl").read_text().splitlines()
                if '"v\\\\xff.mp4"' in line)
    assert '"relative_bytes": "dv8ubXA0"' in line       # base64 of b"v\xff.mp4"
    assert {r["status"] for r in records.values()} == {"done"}
    assert records[ODD_NAME]["outputs"]["detections"] == os.fsdecode(b"v\xff.jsonl")
    assert os.fsencode(records[ODD_NAME]["input"]) == os.fsencode(footage / ODD_NAME)
    for suffix in (b".mp4", b".jsonl", b".jpg"):
        assert (out / os.fsdecode(b"v\xff" + suffix)).stat().st_size > 0
    page = (out / "index.html").read_bytes().decode("utf-8")
    assert 'href="v%FF.jsonl"' in page and "<h2>v\\xff.mp4</h2>" in page
    assert not (out / LOCK_NAME).exists()
    # A re-run finds it done: its record and outputs are found by the name's bytes.
    assert main(["batch", str(footage), "--out-dir", str(out), "--workers", "1", "-q"]) == 0
    assert "2 already done" in capsys.readouterr().out


def test_the_report_and_table_show_an_odd_name_and_link_its_bytes(tmp_path):
    records = [{"relative": ODD_NAME, "status": "failed",
                "reason": f"cannot read /x/{ODD_NAME} as a video"},
               {"relative": "a.mp4", "status": "done", "frames": 1,
                "outputs": {"video": ODD_NAME, "thumbnail": "\ud800.jpg"}}]
    table = summary_table(records)
    table.encode("utf-8")
    assert "failed: v\\xff.mp4: cannot read /x/v\\xff.mp4 as a video" in table
    page = write_report(tmp_path, records).read_bytes().decode("utf-8")
    assert 'src="v%FF.mp4"' in page
    assert 'poster="%5Cud800.jpg"' in page          # a surrogate only an edited manifest has
    assert display_name("café") == "café"


def test_a_rerun_with_other_outputs_removes_what_the_earlier_run_wrote(clip, tmp_path, capsys):
    """A --no-video --format csv re-run left the earlier a.mp4, a.jpg and a.jsonl beside a.csv."""
    footage = tmp_path / "footage"
    footage.mkdir()
    shutil.copy(clip, footage / "a.mp4")
    out = tmp_path / "out"
    assert main(["batch", str(footage), "--out-dir", str(out), "--workers", "1", "-q"]) == 0
    (out / "mine.mp4").write_bytes(b"not the batch's")
    assert main(["batch", str(footage), "--out-dir", str(out), "--workers", "1", "-q",
                 "--no-video", "--format", "csv"]) == 0, capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == ["a.csv", "index.html", "manifest.jsonl",
                                                    "mine.mp4"]
    assert manifest_records(out)["a.mp4"]["outputs"] == {"detections": "a.csv"}


def test_only_files_the_earlier_record_lists_inside_the_folder_are_removed(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    for name in ("a.mp4", "a.jsonl", "b.jsonl", "manifest.jsonl", "link.mp4"):
        (out / name).write_text("x")
    (tmp_path / "outside.mp4").write_text("x")
    (out / "linked.mp4").symlink_to(out / "link.mp4")
    earlier = {"relative": "a.mp4", "status": "done",
               "outputs": {"video": "a.mp4", "detections": "a.jsonl", "x": "b.jsonl",
                           "y": "../outside.mp4", "z": str(tmp_path / "outside.mp4"),
                           "m": "./manifest.jsonl", "l": "linked.mp4"}}
    now = [{"relative": "a.mp4", "status": "done", "outputs": {"detections": "a.jsonl"}},
           {"relative": "b.mp4", "status": "done", "outputs": {"detections": "b.jsonl"}}]
    remove_replaced(earlier, now, out)
    assert sorted(p.name for p in out.iterdir()) == ["a.jsonl", "b.jsonl", "link.mp4",
                                                    "linked.mp4", "manifest.jsonl"]
    assert (tmp_path / "outside.mp4").exists()
    remove_replaced(dict(earlier, status="failed"), [], out)        # a failed record: nothing
    assert (out / "a.jsonl").exists()


def test_the_lock_is_removed_at_the_end_and_a_removed_lock_is_taken_anew(tmp_path, monkeypatch):
    with runner._exclusive(tmp_path):
        assert (tmp_path / LOCK_NAME).is_file()
        with pytest.raises(InputError, match="another fastdet batch is writing"):
            with runner._exclusive(tmp_path):
                pass
    assert not (tmp_path / LOCK_NAME).exists()

    # The run before removes the lock file between this batch's open and its lock: a
    # lock on the removed file would exclude nobody, so the lock is opened again.
    real_flock, calls = fcntl.flock, []

    def flock_after_the_run_before_ended(handle, operation):
        real_flock(handle, operation)
        calls.append(os.fstat(handle.fileno()).st_ino)
        if len(calls) == 1:
            os.unlink(tmp_path / LOCK_NAME)

    monkeypatch.setattr(runner.fcntl, "flock", flock_after_the_run_before_ended)
    with runner._exclusive(tmp_path):
        assert len(calls) == 2 and os.stat(tmp_path / LOCK_NAME).st_ino == calls[1]
    assert not Path(tmp_path / LOCK_NAME).exists()
