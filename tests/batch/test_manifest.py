"""The manifest: records appended as videos finish, last one wins, what makes a video up to date."""

import hashlib
import json
import os

import pytest

from fastdet.batch.manifest import Manifest, file_sha256, input_fingerprint, is_up_to_date
from fastdet.batch.settings import make_settings


def record(relative, status="done", **values):
    return {"relative": relative, "status": status, **values}


def test_records_survive_a_reload_and_the_last_one_wins(tmp_path):
    manifest = Manifest(tmp_path)
    manifest.add(record("a.mp4", "failed", reason="corrupt"))
    manifest.add(record("b.mp4", frames=3))
    manifest.add(record("a.mp4", frames=5))
    again = Manifest(tmp_path)
    assert again.get("a.mp4") == record("a.mp4", frames=5)
    assert again.get("b.mp4")["frames"] == 3
    assert again.get("c.mp4") is None
    again.compact()
    lines = (tmp_path / "manifest.jsonl").read_text().splitlines()
    assert [json.loads(line)["relative"] for line in lines] == ["a.mp4", "b.mp4"]


def test_a_line_torn_by_a_crash_is_ignored_and_ended(tmp_path):
    Manifest(tmp_path).add(record("a.mp4"))
    with open(tmp_path / "manifest.jsonl", "a") as handle:
        handle.write('{"relative": "b.mp4", "sta')          # the process died here
    manifest = Manifest(tmp_path)
    assert list(manifest.records) == ["a.mp4"]
    manifest.add(record("c.mp4"))
    assert sorted(Manifest(tmp_path).records) == ["a.mp4", "c.mp4"]


@pytest.mark.parametrize("line", [
    b'{"relative": "x.mp4"}',                                   # no status
    b'{"relative": "x.mp4", "status": 7}',
    b'{"relative": "x.mp4", "status": "queued"}',
    b'{"relative": "x.mp4", "status": "done", "outputs": 5}',
    b'{"relative": "x.mp4", "status": "done", "outputs": {"video": ["x.mp4"]}}',
    b'{"relative": "x.mp4", "status": "failed", "reason": 3}',
    b'{"relative": "x.mp4", "status": "done", "frames": "<script>"}',
    b'{"relative": "x.mp4", "status": "done", "fps": true}',
    b'{"relative": "x.mp4", "status": "done", "sha256": null}',
    b'{"relative": "\xff.mp4", "status": "done"}',              # not UTF-8
    b'[' * 100000,                                              # nested past the parser
])
def test_a_line_that_is_no_record_is_ignored(tmp_path, line):
    """An edited or foreign manifest: such a line once stopped every later batch
    of the folder with an internal error (a KeyError in the report, a
    UnicodeDecodeError on reading); it counts as a torn line instead."""
    Manifest(tmp_path).add(record("a.mp4", frames=3, outputs={"video": "a.mp4"}))
    with open(tmp_path / "manifest.jsonl", "ab") as handle:
        handle.write(line + b"\n")
    manifest = Manifest(tmp_path)
    assert list(manifest.records) == ["a.mp4"]
    manifest.add(record("c.mp4"))
    assert sorted(Manifest(tmp_path).records) == ["a.mp4", "c.mp4"]


def test_file_hash_and_fingerprint(tmp_path):
    path = tmp_path / "clip.mp4"
    path.write_bytes(os.urandom(3 << 20) + b"tail")
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    assert file_sha256(path) == digest
    info = input_fingerprint(path)
    assert info["sha256"] == digest and info["size"] == (3 << 20) + 4
    # An unchanged file (size and mtime) reuses the recorded hash instead of reading it again.
    assert input_fingerprint(path, dict(info, sha256="recorded"))["sha256"] == "recorded"
    os.utime(path, ns=(info["mtime_ns"] + 10**9, info["mtime_ns"] + 10**9))
    assert input_fingerprint(path, dict(info, sha256="recorded"))["sha256"] == digest


@pytest.fixture
def done(tmp_path):
    settings = make_settings()
    (tmp_path / "a.mp4").write_bytes(b"video")
    (tmp_path / "a.jsonl").write_bytes(b"{}")
    fingerprint = {"size": 1, "mtime_ns": 2, "sha256": "abc"}
    rec = record("a.mp4", **fingerprint, model_sha256=settings.model_sha256,
                 config_sha256=settings.config_sha256,
                 outputs={"video": "a.mp4", "detections": "a.jsonl"})
    return rec, fingerprint, settings


def test_up_to_date_needs_the_same_input_model_config_and_outputs(tmp_path, done):
    rec, fingerprint, settings = done
    assert is_up_to_date(rec, fingerprint, settings, tmp_path)
    assert not is_up_to_date(None, fingerprint, settings, tmp_path)
    assert not is_up_to_date(dict(rec, status="failed"), fingerprint, settings, tmp_path)
    assert not is_up_to_date(rec, dict(fingerprint, sha256="changed"), settings, tmp_path)
    assert not is_up_to_date(rec, fingerprint, make_settings(every=3), tmp_path)
    assert not is_up_to_date(dict(rec, model_sha256="other"), fingerprint, settings, tmp_path)
    (tmp_path / "a.jsonl").unlink()
    assert not is_up_to_date(rec, fingerprint, settings, tmp_path)
