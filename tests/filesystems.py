"""Folders that fail the way real disks do, for the reliability tests.

As root the tests mount the real thing (a tmpfs of a few kilobytes that
fills up, a read-only bind mount); otherwise a read-only folder is made
with ``chmod`` (root ignores file modes, hence the mounts) and a full disk
cannot be made: :func:`tiny_filesystem` yields ``None`` and the tests fall
back to a patched writer.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import stat
import subprocess


def is_root():
    return hasattr(os, "geteuid") and os.geteuid() == 0


def _mount(*args):
    return subprocess.run(["mount", *args], capture_output=True, text=True).returncode == 0


def _unmount(path):
    subprocess.run(["umount", "-l", str(path)], capture_output=True)


@contextlib.contextmanager
def tiny_filesystem(path, size_kib=64):
    """A tmpfs of ``size_kib`` KiB mounted at ``path`` (created), or ``None`` when not root."""
    path.mkdir(parents=True, exist_ok=True)
    if not (is_root() and shutil.which("mount")
            and _mount("-t", "tmpfs", "-o", f"size={size_kib}k,mode=0777", "tmpfs", str(path))):
        yield None
        return
    try:
        yield path
    finally:
        _unmount(path)


@contextlib.contextmanager
def read_only(path):
    """``path`` (an existing folder) made read-only for this process, restored afterwards."""
    if is_root() and shutil.which("mount"):
        if _mount("--bind", str(path), str(path)):
            try:
                if _mount("-o", "remount,bind,ro", str(path)):
                    yield path
                    return
            finally:
                _unmount(path)
    modes = {}
    for root, dirs, files in os.walk(path):
        for name in [root, *(os.path.join(root, f) for f in files)]:
            modes[name] = os.stat(name).st_mode
            os.chmod(name, modes[name] & ~(stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH))
    try:
        yield path
    finally:
        for name, mode in modes.items():
            os.chmod(name, mode)


#: (major, minor) of the Linux character devices the tests stand in for.
DEVICES = {"null": (1, 3), "full": (1, 7)}


def private_device(folder, name, filename=None):
    """A private copy of ``/dev/<name>`` (a device node ``folder/filename``, by default
    ``folder/name``), or ``None`` when not root.

    Tests write to these, never to ``/dev`` itself: code that wrongly
    renames a file over its output would otherwise replace the machine's
    ``/dev/null`` or ``/dev/full`` for every process on it.
    """
    path = folder / (filename or name)
    if not is_root():
        return None
    try:
        os.mknod(path, 0o666 | stat.S_IFCHR, os.makedev(*DEVICES[name]))
    except OSError:
        return None
    return path


def private_stdout(folder):
    """A private symbolic link to this process's standard output, like ``/dev/stdout``."""
    path = folder / "stdout"
    path.symlink_to("/proc/self/fd/1")
    return path
