"""Write files atomically: a reader never sees a half-written output.

:func:`atomic_path` for a file written in one go; :class:`StagedFile` for an
output written piece by piece (a video, a detections file).
"""

import contextlib
import os
import sys
import tempfile
from pathlib import Path

from ..errors import InputError


@contextlib.contextmanager
def atomic_path(path, suffix=None):
    """Yield a temporary path beside ``path``; move it into place on success.

    Parameters
    ----------
    path : str or Path
        Final destination.
    suffix : str, optional
        Suffix of the temporary file (some writers pick the format from it);
        defaults to ``path``'s own suffix.

    On any exception (including ``KeyboardInterrupt``) the temporary file is
    removed and ``path`` is left as it was.
    """
    path = Path(path)
    suffix = path.suffix if suffix is None else suffix
    handle, tmp_name = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".part{suffix}",
                                        dir=path.parent if str(path.parent) else ".")
    os.close(handle)
    tmp = Path(tmp_name)
    # mkstemp creates 0600 files; give the output the permissions a plain open() would.
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def _umask():
    # The only portable way to read the umask is to set it and put it back.
    mask = os.umask(0)
    os.umask(mask)
    return mask


class StagedFile:
    """Base of outputs that appear under their final name only when complete.

    The content goes to a temporary file beside ``path``.  :meth:`close`
    completes it (``_finish``) and renames it to ``path``; :meth:`discard`
    deletes it.  As a context manager, leaving the block normally or by
    ``KeyboardInterrupt`` closes (an interrupted run keeps everything done so
    far, as a complete file), and any other exception discards.

    Parameters
    ----------
    path : str or Path

    Raises
    ------
    InputError
        When ``path`` is a directory or its folder cannot hold a new file.
    """

    def __init__(self, path):
        self.path = Path(path)
        if self.path.is_dir():
            raise InputError(f"cannot write {self.path}: it is a directory")
        self._stack = contextlib.ExitStack()
        try:
            self.temporary = self._stack.enter_context(atomic_path(self.path))
            # mkstemp creates owner-only files; give the output the usual
            # permissions a newly created file gets.
            os.chmod(self.temporary, 0o666 & ~_umask())
        except OSError as exc:
            self._stack.__exit__(*sys.exc_info())
            reason = exc.strerror or str(exc)
            raise InputError(f"cannot write {self.path}: {reason}") from None
        self.closed = False

    def _finish(self):
        """Flush and close the subclass's handle (called by :meth:`close`)."""

    def _abandon(self):
        """Close the subclass's handle without caring about its content."""

    def close(self):
        """Complete the file and move it to its final name (idempotent)."""
        if self.closed:
            return
        self.closed = True
        try:
            self._finish()
        except BaseException:
            self._stack.__exit__(*sys.exc_info())
            raise
        self._stack.close()

    def discard(self):
        """Delete the temporary file; the final name is left untouched (idempotent)."""
        if self.closed:
            return
        self.closed = True
        with contextlib.suppress(Exception):
            self._abandon()
        reason = InputError("output discarded")
        self._stack.__exit__(InputError, reason, None)

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None or issubclass(exc_type, KeyboardInterrupt):
            self.close()
        else:
            self.discard()
        return False
