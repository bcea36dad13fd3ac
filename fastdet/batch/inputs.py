"""What a batch processes: videos, folders of videos, lists of paths; where each one's outputs go.

Every video gets a *relative path* that its outputs mirror under the output
folder: a video named directly keeps its file name, a video found in a folder
its path inside that folder, and a listed video the path as the list writes it
(relative entries are read relative to the list file's folder).
"""

from __future__ import annotations

import os
import re
import stat
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

from ..errors import InputError

#: Suffixes of the files a folder search takes for videos (compared lower-case).
VIDEO_SUFFIXES = frozenset({".mp4", ".m4v", ".mov", ".avi", ".mkv", ".webm", ".mpg", ".mpeg",
                            ".ts", ".mts", ".m2ts", ".wmv", ".flv", ".3gp"})
#: Bytes read to tell a list of paths from a binary file (a video with another suffix).
_TEXT_PROBE = 8192
#: Bytes no list of paths holds but binary files do (controls other than tab, CR, LF, FF, VT).
_BINARY = re.compile(rb"[\x00-\x08\x0e-\x1f\x7f]")


@dataclass(frozen=True)
class VideoInput:
    """One video of a batch.

    Attributes
    ----------
    path : Path
        The file, absolute.
    relative : str
        POSIX path its outputs mirror under the output folder (``day1/clip.mp4``).
    """

    path: Path
    relative: str

    @property
    def key(self):
        """The relative path without its suffix: every output of this video is named after it."""
        return str(PurePosixPath(self.relative).with_suffix(""))


def display_name(text):
    """``text`` (a file name or a message naming files) as printable text.

    A name that is not valid UTF-8 reaches Python with each such byte as a
    lone surrogate (``surrogateescape``), which neither a UTF-8 terminal,
    an HTML page nor Dask's messages can encode; here it shows as ``\\xff``.
    The name itself, with its bytes, is kept for opening the files.
    """
    try:
        raw = os.fsencode(text)
    except UnicodeEncodeError:   # a surrogate no file name decodes to (an edited manifest)
        raw = text.encode("utf-8", "backslashreplace")
    return raw.decode("utf-8", "backslashreplace")


def is_video_name(path):
    """Whether ``path``'s suffix is one a folder search takes for a video."""
    return Path(path).suffix.lower() in VIDEO_SUFFIXES


def find_videos(inputs, exclude=None):
    """The videos that ``inputs`` name, each once, in a stable order.

    Parameters
    ----------
    inputs : iterable of str or Path
        Video files, folders (searched recursively; hidden files and folders
        are left out) and text files listing one path per line (blank lines
        and lines starting with ``#`` are ignored).
    exclude : Path, optional
        A folder whose content is never taken (the output folder, when it
        lies inside an input folder).

    Returns
    -------
    list of VideoInput

    Raises
    ------
    InputError
        When an input does not exist, a list names a missing path, nothing
        is found, or two videos would write the same outputs.
    """
    exclude = None if exclude is None else Path(exclude).resolve()
    found = []
    for item in inputs:
        found += _expand(Path(item), exclude, listed_by=None)
    if not found:
        raise InputError("no videos found in " + ", ".join(str(i) for i in inputs))
    unique, seen_paths, owners = [], set(), {}
    for video in found:
        if video.path in seen_paths:
            continue
        seen_paths.add(video.path)
        other = owners.setdefault(video.key, video)
        if other is not video:
            raise InputError(f"{other.path} and {video.path} would write the same outputs "
                             f"({video.key}.*): rename one or run them in separate batches")
        unique.append(video)
    return unique


def _expand(path, exclude, listed_by):
    # display_name: a listed name that is not UTF-8 shows its bytes as \xff, not \udcff.
    where = f" (listed in {display_name(str(listed_by))})" if listed_by else ""
    if not path.exists():
        raise InputError(f"input not found: {display_name(str(path))}{where}")
    resolved = path.resolve()
    if path.is_dir():
        return [VideoInput(file, file.relative_to(resolved).as_posix())
                for file in _videos_in(resolved, exclude)]
    if not _regular_or_dangling(path):
        # Hashing a FIFO for the manifest would wait for a writer for good.
        raise InputError(f"{display_name(str(path))}{where} is not a regular file (a FIFO, "
                         "socket or device): a batch reads video files")
    if is_video_name(path) or listed_by is not None:
        # A listed file is taken for a video whatever its suffix: the list says so.
        return [VideoInput(resolved, path.name)]
    return _read_list(path, exclude)


def _listed_name(path):
    # A relative entry keeps its folders, unless it climbs out of the list's folder.
    parts = PurePosixPath(path.as_posix()).parts
    if ".." in parts:
        return path.name
    return PurePosixPath(*[p for p in parts if p != "."]).as_posix()


def _videos_in(folder, exclude):
    videos = []
    for root, dirs, files in os.walk(folder):
        root = Path(root)
        dirs[:] = sorted(d for d in dirs if not d.startswith(".")
                         and (exclude is None or (root / d).resolve() != exclude))
        # FIFOs, sockets and devices with a video's name are no videos to take.
        videos += [root / name for name in sorted(files)
                   if not name.startswith(".") and is_video_name(name)
                   and _regular_or_dangling(root / name)]
    return videos


def _regular_or_dangling(path):
    """Whether ``path`` is a regular file or a link to nothing (which then fails
    alone, as a video that cannot be read)."""
    try:
        return stat.S_ISREG(os.stat(path).st_mode)
    except OSError:
        return True


def _read_list(path, exclude):
    with open(path, "rb") as handle:
        head = handle.read(_TEXT_PROBE)
    if _BINARY.search(head):
        raise InputError(f"{path} is neither a video (by its suffix: "
                         f"{', '.join(sorted(VIDEO_SUFFIXES))}) nor a text file listing "
                         "videos")
    # Each line is a file name, decoded as the file system decodes names: a name that is
    # not UTF-8 (`find > list.txt` in a folder holding one) keeps its bytes, as a video
    # named directly does; strict UTF-8 refused the whole list as not text.  A byte
    # order mark (Notepad's UTF-8) is no part of the first name.
    data = path.read_bytes().removeprefix(b"\xef\xbb\xbf")
    text = [os.fsdecode(line) for line in data.splitlines()]
    entries = []
    for line in text:
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        written = Path(line).expanduser()
        entry = written if written.is_absolute() else path.parent / written
        expanded = _expand(entry, exclude, listed_by=path)
        if not written.is_absolute() and not entry.is_dir():
            expanded = [VideoInput(v.path, _listed_name(written)) for v in expanded]
        entries += expanded
    return entries
