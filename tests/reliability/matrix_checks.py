"""The bad-input matrix's machinery: a :class:`Row` per fault, and the checks every row gets.

The rows themselves are data, by verb: ``test_matrix.py`` (images, models,
configs, annotations, training data) and ``matrix_video_rows.py`` (``run`` and its
stream inputs).
"""

from __future__ import annotations

import contextlib
import os
import re
import subprocess
import sys
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import pytest

from fastdet.cli.app import EXIT_ERROR, main
from fastdet.files.atomic import is_temporary
from filesystems import read_only, tiny_filesystem

ROOT = Path(__file__).resolve().parents[2]
FASTDET = [sys.executable, "-c",
           "import sys; from fastdet.cli import console_main; console_main(sys.argv[1:])"]
#: Lines besides the error a command may print on stderr: the notice that
#: kernels are compiling, and the progress lines of training and tuning.
NOTICE = re.compile(r"^(fastdet: compiling kernels|\d+ crops \(|features: |random split: |"
                    r"leak-free split: |cross-validation C=|chosen C=|\d+ combinations on )")


class InputFolder:
    """The files a set of rows reads, made in the folder ``self.dir``."""

    def file(self, name, data):
        path = self.dir / name
        path.write_bytes(data)
        return path

    def __truediv__(self, name):
        return self.dir / name


@dataclass
class Row:
    """One fault of one verb and the behaviour promised.

    ``argv(inputs, out)`` builds the command line (``out``: the row's own
    empty folder); ``names(inputs, out)`` the file the error line must name;
    ``problem`` a regular expression it must match; ``guarded(inputs, out)``
    the files that must end up as they started; ``setup(inputs, out)`` a
    context manager around the run (a mount, a reader); ``check(inputs, out,
    stdout)`` what a successful run must have produced; ``messages`` the
    lines a successful run prints on stderr (when stdout holds the output).
    """

    verb: str
    fault: str
    argv: Callable
    code: int = EXIT_ERROR
    names: Callable | None = None
    problem: str = ""
    guarded: Callable = lambda i, o: []
    setup: Callable | None = None
    check: Callable | None = None
    subprocess: bool = False
    messages: str = "^$"

    @property
    def id(self):
        return f"{self.verb}: {self.fault}"


def s(path):
    return str(path)


@contextlib.contextmanager
def full_disk(folder, previous_size=9000):
    """``folder/disk``: a 16 KiB disk holding a file ``previous`` (rows run as root only)."""
    with tiny_filesystem(folder / "disk", size_kib=16) as disk:
        if disk is None:
            pytest.skip("a full disk needs root to mount a tmpfs")
        (disk / "previous").write_bytes(b"p" * previous_size)
        yield disk


@contextlib.contextmanager
def read_only_out(folder):
    with read_only(folder):
        yield folder


@contextlib.contextmanager
def fifo_reader(path, received):
    """A FIFO at ``path`` whose reader appends what it read to ``received`` (emptied first)."""
    received.clear()
    os.mkfifo(path)
    # A daemon: should the FIFO be replaced instead of written (the bug this
    # row guards against), the reader waits forever, but the tests go on.
    reader = threading.Thread(target=lambda: received.append(path.read_bytes()), daemon=True)
    reader.start()
    try:
        yield
    finally:
        reader.join(timeout=60)


# -- the checks ----------------------------------------------------------------------
def snapshot(paths):
    return {str(p): (Path(p).read_bytes() if Path(p).is_file() else None) for p in paths}


def leftovers(*folders):
    found = []
    for folder in folders:
        for root, _, files in os.walk(folder):
            found += [os.path.join(root, f) for f in files if is_temporary(f) or ".part" in f]
    return found


def run_row(row, argv, capfd):
    if row.subprocess:
        result = subprocess.run([*FASTDET, *argv], cwd=ROOT, capture_output=True, timeout=600)
        return result.returncode, result.stdout, result.stderr.decode()
    code = main(argv)
    captured = capfd.readouterr()
    return code, captured.out.encode(), captured.err


def check_row(row, inputs, tmp_path, capfd):
    """Run ``row`` in its own ``tmp_path`` and hold it to every promise (module notes)."""
    out = tmp_path / "out"
    out.mkdir()
    setup = row.setup(inputs, out) if row.setup else contextlib.nullcontext()
    with setup:
        argv = row.argv(inputs, out)
        guarded = row.guarded(inputs, out)
        before = snapshot(guarded)
        capfd.readouterr()
        code, stdout, stderr = run_row(row, argv, capfd)
        after = snapshot(guarded)
        left = leftovers(out, inputs.dir)
        assert "Traceback" not in stderr, stderr
        lines = [line for line in stderr.splitlines() if not NOTICE.match(line)]
        assert code == row.code, f"exit {code}, stderr: {stderr}"
        if row.code == EXIT_ERROR:
            assert len(lines) == 1 and lines[0].startswith("fastdet: error: "), stderr
            problem = lines[0]
            if row.names is not None:
                named = str(row.names(inputs, out))
                assert named in lines[0], lines[0]
                problem = problem.replace(named, "<file>")  # the problem, not the file's name
            assert re.search(row.problem, problem), lines[0]
        else:
            assert all(re.search(row.messages, line) for line in lines), stderr
        assert after == before, "a guarded file changed"
        assert not left, f"temporary files left: {left}"
    # After the setup's end: a FIFO's reader has then read everything.
    if row.code != EXIT_ERROR and row.check is not None:
        assert row.check(inputs, out, stdout)


# -- the table of docs/reliability.md --------------------------------------------------
TABLE_HEADER = ("| verb | fault | exit | the error line names the file and says |",
                "|---|---|---:|---|")


def outcome(row):
    """The last column of ``row``'s line in the table."""
    if row.code == EXIT_ERROR:
        return " or ".join(f"`{part}`" for part in row.problem.split("|")) or "(an error)"
    if row.code == 1:
        return "(some videos failed: each one's status and reason are in the manifest)"
    if row.messages == "^$":
        return "(handled)"
    if "warning" in row.messages:
        return "(handled; one line on stderr: `fastdet: warning: <file>: input damaged: ...`)"
    return "(handled; stdout holds the output, messages go to stderr)"


def markdown_table(rows):
    """The matrix as the markdown table of ``docs/reliability.md``, one line per row."""
    return "\n".join([*TABLE_HEADER, *(f"| {row.verb} | {row.fault} | {row.code} | "
                                       f"{outcome(row)} |" for row in rows)])
