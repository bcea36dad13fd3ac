"""Standard output whose reader went away (``fastdet run ... --detections - | head``).

``head`` closes its end of the pipe once it has what it wants, and Unix tools
then stop quietly.  The run's outputs raise :class:`ReaderGone` for it, only
when they write standard output: a write error on a file (a FIFO's reader
gone included) stays an error.
"""

from __future__ import annotations

import contextlib
import os
import sys

from ..errors import InputError
from ..files.atomic import is_standard_output


class ReaderGone(InputError):
    """The reader of standard output closed it; the output takes nothing more."""

    def __init__(self, path):
        super().__init__(f"cannot write {path}: the reader of standard output went away")


def writes_standard_output(path):
    """Whether ``path`` is this process's standard output (``-``, ``/dev/stdout``, a
    name of the pipe or file it is)."""
    if is_standard_output(path):
        return True
    with contextlib.suppress(OSError, ValueError):
        return os.path.samestat(os.stat(path), os.fstat(sys.stdout.fileno()))
    return False


class PipeWatch:
    """A binary file for PyAV that remembers a write failing on a closed pipe.

    PyAV keeps a write error of a Python file to itself until the container
    closes, so a video sent to ``| head`` would otherwise be encoded to the end.
    """

    def __init__(self, handle):
        self._handle = handle
        self.broken = False

    def write(self, data):
        try:
            return self._handle.write(data)
        except BrokenPipeError:
            self.broken = True
            raise

    def __getattr__(self, name):
        return getattr(self._handle, name)
