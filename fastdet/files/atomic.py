"""Write outputs so that a reader never sees half of one.

:func:`atomic_path` for a file written in one go; :class:`StagedFile` for an
output written piece by piece (a video, a detections file).

What an output path may be, and what happens:

* a regular file, or a name that does not exist yet: the content goes to a
  temporary file in the same folder, renamed over the final name when
  complete; on any failure the temporary file is removed and the final name
  is left as it was;
* a symbolic link: it is followed: its target is written atomically as
  above and the link is kept (a link that names its output, say
  ``latest.jsonl -> run-42.jsonl``, keeps working);
* ``-`` (standard output), a FIFO, a character device (``/dev/stdout``,
  ``/dev/null``, ``/dev/full``) or anything else that is not a regular
  file: written through in place, never replaced by a rename;
* a folder: refused.

A failure to write (a full disk, a read-only folder) becomes an
:class:`~fastdet.errors.InputError` naming the file.

Temporary files are named ``.<stem>.<pid>-<random>.part<suffix>``: hidden,
never matching the output's own name or suffix, so no reader takes one for
an output (:func:`is_temporary` recognises them; the training data lister
skips them).  A process killed outright (``SIGKILL``) cannot remove its
temporary file; the next fastdet process writing into the same folder
deletes every such file whose process is gone.

:func:`check_writable` checks an output before long work.

Names built from *input* names (``fastdet detect --out-dir``, ``fastdet
mine --out``) go through :func:`output_in_folder`, which never leaves the
folder: no ``..``, no separators, and no symbolic link is followed there.
"""

from __future__ import annotations

import contextlib
import functools
import os
import re
import shutil
import stat
import sys
import tempfile
from pathlib import Path

from ..errors import InputError

#: The name that means standard output.
STDOUT = "-"
#: Other names of this process's standard output: written through its
#: descriptor like ``-``, whatever it is redirected to.  Followed as links,
#: ``> out.mp4`` made them a regular file to replace, one whose name has no
#: suffix to choose a format by.
STDOUT_ALIASES = ("/dev/stdout", "/dev/fd/1", "/proc/self/fd/1")


def is_standard_output(path):
    """Whether ``path`` names this process's standard output (``-``, ``/dev/stdout``, ...)."""
    return str(path) == STDOUT or os.path.normpath(str(path)) in STDOUT_ALIASES

#: ``.<stem>.<pid>-<random>.part<suffix>``, as :func:`_temporary_in` names them.
_TEMPORARY = re.compile(r"^\.(?P<stem>.*)\.(?P<pid>\d+)-[^.]+\.part(?P<suffix>\.[^.]*)?$")


def is_temporary(path):
    """Whether ``path`` is the temporary file of an output being written (or left by a crash)."""
    return _TEMPORARY.match(Path(path).name) is not None


def _alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # another user's process: alive
        return True
    return True


@functools.lru_cache(maxsize=None)
def _remove_stale_temporaries(folder):
    """Delete the temporary files of dead fastdet processes in ``folder`` (once per process)."""
    with contextlib.suppress(OSError):
        for entry in os.scandir(folder):
            match = _TEMPORARY.match(entry.name)
            if match and not _alive(int(match.group("pid"))):
                with contextlib.suppress(OSError):
                    os.unlink(entry.path)


def _umask():
    # The only portable way to read the umask is to set it and put it back.
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _reason(exc):
    return exc.strerror or " ".join(str(exc).split()) or type(exc).__name__


def _in_place(path):
    """Whether ``path`` is written through in place (standard output, or not a regular file)."""
    if is_standard_output(path):
        return True
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return False  # does not exist (or a dangling link): created as a regular file
    if stat.S_ISDIR(mode):
        raise InputError(f"cannot write {path}: it is a directory")
    return not stat.S_ISREG(mode)


def _final(path):
    """The regular file that is replaced: ``path``, or the end of its symbolic links."""
    return Path(os.path.realpath(path)) if os.path.islink(path) else path


def _temporary_in(folder, final, suffix):
    """Create the temporary file of ``final`` in ``folder``; returns its Path."""
    _remove_stale_temporaries(str(folder))
    handle, name = tempfile.mkstemp(prefix=f".{final.stem}.{os.getpid()}-",
                                    suffix=f".part{suffix}", dir=folder)
    os.close(handle)
    try:
        mode = stat.S_IMODE(os.stat(final).st_mode)
    except OSError:
        mode = 0o666 & ~_umask()  # mkstemp makes 0600 files; a plain open() would not
    os.chmod(name, mode)
    return Path(name)


def _copy_into(source, target):
    """Append the bytes of ``source`` to ``target``, a stream (``-``) or a special file."""
    with open(source, "rb") as data:
        if is_standard_output(target):
            sys.stdout.flush()
            shutil.copyfileobj(data, sys.stdout.buffer)
            sys.stdout.buffer.flush()
        else:
            with open(target, "ab") as out:
                shutil.copyfileobj(data, out)


@contextlib.contextmanager
def atomic_path(path, suffix=None):
    """Yield a temporary path to write; on success it becomes ``path`` (see the module notes).

    Parameters
    ----------
    path : str or Path
        Final destination: a file (a symbolic link is followed), ``-`` for
        standard output, or a FIFO or device, which receive the content
        once it is complete.
    suffix : str, optional
        Suffix of the temporary file (some writers pick the format from it);
        defaults to ``path``'s own suffix.

    Raises
    ------
    InputError
        When ``path`` is a folder, or cannot be written (naming it and why).

    On any exception (including ``KeyboardInterrupt``) the temporary file is
    removed and ``path`` is left as it was.
    """
    path = Path(path)
    suffix = path.suffix if suffix is None else suffix
    in_place = _in_place(path)
    final = path if in_place else _final(path)
    try:
        folder = Path(tempfile.gettempdir()) if in_place else (final.parent if str(final.parent)
                                                                else Path("."))
        tmp = _temporary_in(folder, final, suffix)
    except OSError as exc:
        raise InputError(f"cannot write {path}: {_reason(exc)}") from None
    try:
        yield tmp
        if in_place:
            _copy_into(tmp, path)
        else:
            os.replace(tmp, final)
    except OSError as exc:
        raise InputError(f"cannot write {path}: {_reason(exc)}") from None
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink()


class StagedFile:
    """Base of outputs that appear under their final name only when complete.

    The content goes to :attr:`temporary`, a file beside ``path``;
    :meth:`close` completes it (``_finish``) and renames it to ``path``;
    :meth:`discard` deletes it.  For ``-``, a FIFO or a device (see the
    module notes) :attr:`temporary` is the output itself (``/dev/stdout``
    for ``-``), written through in place: :meth:`close` only completes it and
    :meth:`discard` leaves it alone.  As a context manager, leaving the block
    normally or by ``KeyboardInterrupt`` closes (an interrupted run keeps
    everything done so far, as a complete file), and any other exception
    discards.

    Subclasses open :attr:`temporary` themselves, or with :meth:`open`,
    which also writes ``-`` through this process's own standard output, and
    wrap their writes in :meth:`writing`.

    Parameters
    ----------
    path : str or Path

    Attributes
    ----------
    path : Path
        The output as given.
    temporary : Path
        Where to write.
    in_place : bool
        Whether the output is written through in place.

    Raises
    ------
    InputError
        When ``path`` is a directory or its folder cannot hold a new file.
    """

    def __init__(self, path):
        self.path = Path(path)
        self.in_place = _in_place(self.path)
        self._stack = contextlib.ExitStack()
        self.closed = False
        if self.in_place:
            self.temporary = Path("/dev/stdout") if is_standard_output(path) else self.path
            return
        try:
            self.temporary = self._stack.enter_context(atomic_path(self.path))
        except InputError:
            self._stack.close()
            raise

    def open(self, mode="w", **kwargs):
        """Open :attr:`temporary` like :func:`open`; ``-`` appends to this process's stdout.

        Standard output is duplicated rather than reopened, so the output
        continues what was already printed, also when it is redirected to a
        regular file (reopening ``/dev/stdout`` would truncate that file).
        """
        if is_standard_output(self.path):
            sys.stdout.flush()
            return open(os.dup(sys.stdout.fileno()), mode, closefd=True, **kwargs)
        return open(self.temporary, mode, **kwargs)

    @contextlib.contextmanager
    def writing(self):
        """Wrap a subclass's writes: an ``OSError`` (a full disk) becomes an InputError.

        The error names the file.  An exception leaving a ``with`` block of
        the file itself may come from anywhere (reading the input, say), so
        only the writes are wrapped.
        """
        try:
            yield
        except OSError as exc:
            raise InputError(f"cannot write {self.path}: {_reason(exc)}") from None

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
        except OSError as exc:
            self._stack.__exit__(*sys.exc_info())
            raise InputError(f"cannot write {self.path}: {_reason(exc)}") from None
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
        with contextlib.suppress(InputError):
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


def check_writable(path):
    """Raise :class:`InputError` now if ``path`` clearly cannot be written later.

    For commands that work long before they write (training, tuning): a
    folder given as a file, a missing or read-only folder fail at once.  A
    disk that fills up meanwhile still fails at the write, cleanly.
    """
    if path is None or _in_place(Path(path)):
        return
    folder = _final(Path(path)).parent
    if not folder.is_dir():
        raise InputError(f"cannot write {path}: folder {folder} not found")
    if not os.access(folder, os.W_OK):
        raise InputError(f"cannot write {path}: folder {folder} is not writable")


def output_folder(folder, option="--out-dir"):
    """Create ``folder`` (and its parents) for outputs, or raise a one-line :class:`InputError`.

    Parameters
    ----------
    folder : str or Path
    option : str
        How the user named it, for the message.

    Returns
    -------
    Path
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise InputError(f"{option} {folder} is not a folder")
    try:
        folder.mkdir(parents=True, exist_ok=True)
        # Fail before any work, not at the first write; a nameless file (O_TMPFILE
        # on Linux) leaves nothing behind even if the process is killed here.
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as exc:
        # A parent that is a file, a read-only folder, another user's: name the folder.
        raise InputError(f"cannot write into {option} {folder}: {_reason(exc)}") from None
    return folder


def output_in_folder(folder, name):
    """``folder / name`` for a name built from an input's name, kept inside ``folder``.

    Parameters
    ----------
    folder : str or Path
    name : str
        A file name (no folder part).

    Raises
    ------
    InputError
        When ``name`` is empty, ``.`` or ``..`` or holds a separator, or when
        ``folder / name`` is a symbolic link (which could point anywhere) or
        a folder.
    """
    folder = Path(folder)
    separators = {"/", os.sep, "\0"}
    if name in ("", ".", "..") or any(mark in name for mark in separators):
        raise InputError(f"cannot name an output {name!r} in {folder}")
    path = folder / name
    if os.path.islink(path):
        raise InputError(f"refusing to write {path}: it is a symbolic link, which could lead "
                         f"outside {folder}")
    if path.is_dir():
        raise InputError(f"cannot write {path}: it is a directory")
    return path


def same_file(output, inputs):
    """The first of ``inputs`` that ``output`` would overwrite (the same file), else ``None``."""
    for candidate in inputs:
        with contextlib.suppress(OSError):
            if os.path.samefile(output, candidate):
                return candidate
    return None


def refuse_overwriting_inputs(output, inputs):
    """Raise :class:`InputError` when writing ``output`` would replace one of ``inputs``."""
    if output is None or str(output) == STDOUT:
        return
    clash = same_file(output, [p for p in inputs if p is not None])
    if clash is not None:
        raise InputError(f"cannot write {output}: it is the input {clash}; choose another name")
