"""Atomic outputs (fastdet/files/atomic.py): regular files, links, streams, devices, full disks."""

from __future__ import annotations

import errno
import os
import signal
import stat
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from fastdet.errors import InputError
from fastdet.files import atomic
from fastdet.files.atomic import (
    StagedFile,
    atomic_path,
    is_temporary,
    output_in_folder,
    refuse_overwriting_inputs,
)
from filesystems import private_device, private_stdout, read_only, tiny_filesystem

ROOT = Path(__file__).resolve().parents[2]


class LineFile(StagedFile):
    """A minimal streaming output: lines written through :meth:`StagedFile.open`."""

    def __init__(self, path):
        super().__init__(path)
        self.handle = self.open("w")

    def write(self, text):
        with self.writing():
            self.handle.write(text)

    def _finish(self):
        self.handle.close()

    def _abandon(self):
        self.handle.close()


def temporaries(folder):
    return sorted(p.name for p in Path(folder).iterdir() if ".part" in p.name)


@pytest.fixture(autouse=True)
def fresh_stale_scan():
    # Stale temporaries are looked for once per folder and process.
    atomic._remove_stale_temporaries.cache_clear()


# -- regular files and links ----------------------------------------------------
def test_regular_file_is_replaced_only_when_complete(tmp_path):
    path = tmp_path / "out.txt"
    path.write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_path(path) as tmp:
            tmp.write_text("half")
            raise RuntimeError("writer failed")
    assert path.read_text() == "old" and not temporaries(tmp_path)
    with atomic_path(path) as tmp:
        assert is_temporary(tmp) and tmp.parent == tmp_path
        tmp.write_text("new")
    assert path.read_text() == "new" and not temporaries(tmp_path)


def test_existing_permissions_are_kept(tmp_path):
    path = tmp_path / "out.txt"
    path.write_text("old")
    os.chmod(path, 0o640)
    with atomic_path(path) as tmp:
        tmp.write_text("new")
    assert stat.S_IMODE(os.stat(path).st_mode) == 0o640


def test_symlink_is_followed_and_kept(tmp_path):
    target = tmp_path / "runs" / "run-42.jsonl"
    target.parent.mkdir()
    target.write_text("old")
    link = tmp_path / "latest.jsonl"
    link.symlink_to(target)
    with LineFile(link) as out:
        out.write("new\n")
    assert link.is_symlink() and os.readlink(link) == str(target)
    assert target.read_text() == "new\n"
    assert not temporaries(tmp_path) and not temporaries(target.parent)


def test_dangling_symlink_creates_its_target(tmp_path):
    link = tmp_path / "out.txt"
    link.symlink_to(tmp_path / "target.txt")
    with atomic_path(link) as tmp:
        tmp.write_text("x")
    assert link.is_symlink() and (tmp_path / "target.txt").read_text() == "x"


def test_directory_is_refused(tmp_path):
    with pytest.raises(InputError, match="is a directory"):
        with atomic_path(tmp_path):
            pass
    with pytest.raises(InputError, match="is a directory"):
        LineFile(tmp_path)


# -- streams and devices: written through, never replaced ------------------------
def run_python(code, stdout):
    return subprocess.run([sys.executable, "-c", code], cwd=ROOT, stdout=stdout,
                          stderr=subprocess.PIPE, text=True, timeout=120)


def test_dash_writes_to_stdout_after_what_was_printed(tmp_path):
    # stdout redirected to a regular file: printed lines and the output follow
    # each other (reopening /dev/stdout would have truncated the file).
    code = ("from fastdet.files.atomic import StagedFile, atomic_path\n"
            "print('before', flush=True)\n"
            "out = StagedFile('-'); handle = out.open('w'); handle.write('staged\\n')\n"
            "handle.close(); out.close()\n"
            "with atomic_path('-') as tmp: tmp.write_text('atomic\\n')\n"
            "print('after')\n")
    log = tmp_path / "stdout.txt"
    with open(log, "w") as handle:
        result = run_python(code, handle)
    assert result.returncode == 0, result.stderr
    assert log.read_text() == "before\nstaged\natomic\nafter\n"
    assert not [p for p in Path("/tmp").glob(".tmp*.part*") if p.stat().st_uid == os.getuid()
                and time.time() - p.stat().st_mtime < 60]


def test_dash_through_a_pipe():
    code = ("from fastdet.files.atomic import StagedFile\n"
            "out = StagedFile('-'); handle = out.open('w'); handle.write('line\\n')\n"
            "handle.close(); out.close()\n")
    result = run_python(code, subprocess.PIPE)
    assert result.returncode == 0 and result.stdout == "line\n", result.stderr


def test_fifo_is_written_through(tmp_path):
    fifo = tmp_path / "dets.fifo"
    os.mkfifo(fifo)
    received = []
    reader = threading.Thread(target=lambda: received.append(fifo.read_text()))
    reader.start()
    with LineFile(fifo) as out:
        assert out.in_place and out.temporary == fifo
        out.write("frame 0\n")
    reader.join(timeout=10)
    assert received == ["frame 0\n"]
    assert stat.S_ISFIFO(os.stat(fifo).st_mode) and not temporaries(tmp_path)
    reader = threading.Thread(target=lambda: received.append(fifo.read_text()))
    reader.start()
    with atomic_path(fifo) as tmp:
        tmp.write_text("whole\n")
    reader.join(timeout=10)
    assert received[-1] == "whole\n" and stat.S_ISFIFO(os.stat(fifo).st_mode)


@pytest.fixture
def device(tmp_path):
    """A private device node standing in for /dev/<name> (tests never write to /dev itself)."""
    def make(name):
        path = private_device(tmp_path, name)
        if path is None:
            pytest.skip("needs root to make a device node")
        return path
    return make


def test_full_device_says_disk_full_and_stays_a_device(device):
    full = device("full")
    message = rf"^cannot write {full}: No space left on device$"
    with pytest.raises(InputError, match=message):
        with atomic_path(full) as tmp:
            tmp.write_bytes(b"x" * 10000)
    with pytest.raises(InputError, match=message):
        with LineFile(full) as out:
            out.write("x" * 100000)
    assert stat.S_ISCHR(os.stat(full).st_mode)


def test_null_device_and_stdout_link_stay_what_they_are(device, tmp_path):
    null = device("null")
    with atomic_path(null) as tmp:
        tmp.write_text("x")
    with LineFile(null) as out:
        out.write("x")
    assert stat.S_ISCHR(os.stat(null).st_mode)
    stdout = private_stdout(tmp_path)  # what /dev/stdout is: a link to /proc/self/fd/1
    code = ("import sys\nfrom fastdet.files.atomic import atomic_path\n"
            "with atomic_path(sys.argv[1]) as tmp: tmp.write_text('through\\n')\n")
    result = subprocess.run([sys.executable, "-c", code, str(stdout)], cwd=ROOT,
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0 and result.stdout == "through\n", result.stderr
    assert stdout.is_symlink() and os.readlink(stdout) == "/proc/self/fd/1"


# -- failures: one line naming the file, nothing half-written, nothing left --------
def fill(tmp, size):
    with open(tmp, "wb") as handle:
        handle.write(b"\0" * size)


def test_disk_full(tmp_path, monkeypatch):
    with tiny_filesystem(tmp_path / "mnt", size_kib=64) as disk:
        if disk is None:
            # Not root: a writer that fails as a full disk makes it fail.
            disk = tmp_path

            def fill(tmp, size):  # noqa: F811 - the patched writer
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        else:
            fill = globals()["fill"]
        path = disk / "model.npz"
        path.write_bytes(b"previous")
        with pytest.raises(InputError) as info:
            with atomic_path(path) as tmp:
                fill(tmp, 1 << 20)
        assert str(info.value) == f"cannot write {path}: No space left on device"
        assert path.read_bytes() == b"previous" and not temporaries(disk)


def test_read_only_folder(tmp_path):
    folder = tmp_path / "out"
    folder.mkdir()
    with read_only(folder):
        if os.access(folder, os.W_OK) and os.geteuid() != 0:
            pytest.skip("cannot make a read-only folder here")
        with pytest.raises(InputError, match=f"^cannot write {folder / 'x.txt'}: "):
            with atomic_path(folder / "x.txt"):
                pass
        with pytest.raises(InputError, match="^cannot write "):
            LineFile(folder / "x.txt")
    assert not list(folder.iterdir())


# -- temporaries left by a killed process ------------------------------------------
def test_temporary_names():
    assert is_temporary(".dets.1234-ab_c9xyz.part.jsonl")
    assert is_temporary(".model.7-k2j3h4g5.part")
    assert not is_temporary("dets.jsonl") and not is_temporary(".dets.jsonl")
    assert not is_temporary("dets.1234-abc.part.jsonl")


def test_sigkill_leaves_a_temporary_the_next_run_removes(tmp_path):
    code = ("import sys, time\nfrom fastdet.files.atomic import StagedFile\n"
            f"out = StagedFile({str(tmp_path / 'dets.jsonl')!r})\n"
            "out.open('w').write('half')\nprint(out.temporary, flush=True)\ntime.sleep(60)\n")
    child = subprocess.Popen([sys.executable, "-c", code], cwd=ROOT, stdout=subprocess.PIPE,
                             text=True)
    temporary = Path(child.stdout.readline().strip())
    os.kill(child.pid, signal.SIGKILL)
    child.wait(timeout=30)
    assert temporary.exists() and is_temporary(temporary)
    assert not (tmp_path / "dets.jsonl").exists()
    # A temporary of a live process is someone's output being written: kept.
    alive = tmp_path / f".other.{os.getpid()}-abcdefgh.part.jsonl"
    alive.write_text("busy")
    with atomic_path(tmp_path / "dets.jsonl") as tmp:
        tmp.write_text("complete\n")
    assert not temporary.exists() and alive.exists()
    assert (tmp_path / "dets.jsonl").read_text() == "complete\n"


# -- names built from input names --------------------------------------------------
@pytest.mark.parametrize("name", ["..", ".", "", "../x.png", "a/b.png", "x\0.png"])
def test_names_never_leave_the_folder(tmp_path, name):
    with pytest.raises(InputError):
        output_in_folder(tmp_path, name)


def test_symlink_in_the_output_folder_is_refused(tmp_path):
    outside = tmp_path / "outside.png"
    folder = tmp_path / "out"
    folder.mkdir()
    (folder / "test1.jpg").symlink_to(outside)
    with pytest.raises(InputError, match="symbolic link"):
        output_in_folder(folder, "test1.jpg")
    assert output_in_folder(folder, "test2.jpg") == folder / "test2.jpg"


def test_output_equal_to_an_input_is_refused(tmp_path):
    image = tmp_path / "a.jpg"
    image.write_bytes(b"x")
    (tmp_path / "link.jpg").symlink_to(image)
    for output in (image, tmp_path / "link.jpg", tmp_path / "." / "a.jpg"):
        with pytest.raises(InputError, match="it is the input"):
            refuse_overwriting_inputs(output, [None, str(image)])
    refuse_overwriting_inputs(tmp_path / "b.jpg", [image])
    refuse_overwriting_inputs("-", [image])


@pytest.mark.parametrize("alias", ["/dev/stdout", "/dev/fd/1", "/proc/self/fd/1"])
def test_a_name_of_standard_output_redirected_to_a_file_is_written_through(tmp_path, alias):
    """``--out /dev/stdout > out.mp4``: followed as a link, the name was a regular file to
    replace (reopening it truncated what stdout held) and had no suffix to choose a format by."""
    script = ("import sys; from fastdet.files.atomic import atomic_path, StagedFile\n"
              "print('before', flush=True)\n"
              "with atomic_path(sys.argv[1]) as tmp: tmp.write_text('atomic\\n')\n"
              "class Text(StagedFile):\n"
              "    def write(self, text):\n"
              "        with self.open('a') as handle: handle.write(text)\n"
              "staged = Text(sys.argv[1]); assert staged.in_place\n"
              "staged.write('staged\\n'); staged.close()\n")
    out = tmp_path / "out.txt"
    with open(out, "w") as handle:
        subprocess.run([sys.executable, "-c", script, alias], stdout=handle, check=True,
                       timeout=60)
    assert out.read_text() == "before\natomic\nstaged\n"
    assert list(tmp_path.iterdir()) == [out]
