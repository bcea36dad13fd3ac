"""Where one video's outputs go under the output folder, and the litter of killed attempts.

For an input whose relative path is ``day1/clip.mp4`` the outputs are
``DIR/day1/clip.mp4`` (annotated video), ``DIR/day1/clip.jsonl`` (or ``.csv``,
``.txt`` for MOT) and ``DIR/day1/clip.jpg`` (thumbnail of the report page).
Segments of a long video are written to ``DIR/.fastdet-parts/day1/clip/``
and merged; the folder is removed when the video is done.  No output may
take the name of one of the batch's own files (:data:`BATCH_FILES`): a video
named ``manifest.mp4`` would write its detections over the manifest.
"""

from __future__ import annotations

import contextlib
import shutil
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

from ..errors import InputError
from .inputs import display_name
from .manifest import MANIFEST_NAME
from .report import REPORT_NAME

#: Hidden folder (folder searches skip it) for the segments of long videos.
PARTS_FOLDER = ".fastdet-parts"
#: The lock a batch holds on its output folder while it runs.
LOCK_NAME = ".fastdet-batch.lock"
#: What the batch itself keeps in the output folder, by name: no video's output may be one.
BATCH_FILES = {MANIFEST_NAME: "manifest", REPORT_NAME: "report page", LOCK_NAME: "lock",
               PARTS_FOLDER: "folder of segments"}


@dataclass(frozen=True)
class OutputPaths:
    """The files written for one video (``None``: not written)."""

    video: Path | None
    detections: Path | None
    thumbnail: Path | None

    def files(self):
        """The paths that are written, in a fixed order."""
        return [p for p in (self.video, self.detections, self.thumbnail) if p is not None]

    def as_dict(self):
        """``{"video": str or None, ...}``: what a task receives."""
        return {name: None if path is None else str(path)
                for name, path in (("video", self.video), ("detections", self.detections),
                                   ("thumbnail", self.thumbnail))}

    @classmethod
    def from_dict(cls, paths):
        """The inverse of :meth:`as_dict`."""
        return cls(**{name: None if path is None else Path(path) for name, path in paths.items()})

    def relative_to(self, out_dir):
        """``{"video": "day1/clip.mp4", ...}`` relative to ``out_dir``, as the manifest stores them."""
        return {name: Path(path).relative_to(out_dir).as_posix()
                for name, path in (("video", self.video), ("detections", self.detections),
                                   ("thumbnail", self.thumbnail)) if path is not None}


def output_paths(video, out_dir, settings):
    """The :class:`OutputPaths` of a :class:`~fastdet.batch.inputs.VideoInput`.

    Raises
    ------
    InputError
        When an output would overwrite the input video itself, or one of the
        batch's own files (:data:`BATCH_FILES`).
    """
    base = Path(out_dir) / video.key
    paths = OutputPaths(
        video=base.with_name(base.name + ".mp4") if settings.write_video else None,
        detections=(base.with_name(base.name + settings.detections_suffix())
                    if settings.detections_format else None),
        thumbnail=base.with_name(base.name + ".jpg") if settings.write_video else None)
    for path in paths.files():
        if path.resolve() == video.path:
            raise InputError(f"{path} would overwrite the input video: choose another --out-dir")
        top = path.relative_to(out_dir).parts[0]
        if top in BATCH_FILES:
            raise InputError(f"{display_name(str(video.path))} would write "
                             f"{display_name(str(path))}, the batch's {BATCH_FILES[top]}: "
                             "rename the video or move it into a subfolder")
    return paths


def check_outputs(videos, out_dir, settings):
    """Refuse, before any work, a batch where an output of a video would replace an input
    or one of the batch's own files (see :func:`output_paths`)."""
    for video in videos:
        output_paths(video, out_dir, settings)


def parts_folder(out_dir, video):
    """The folder holding the segments of ``video`` while they are merged."""
    return Path(out_dir) / PARTS_FOLDER / video.key


def remove_leftovers(paths, parts=None):
    """Delete what killed attempts left beside ``paths``: temporary files and segments.

    Outputs are written to ``.<stem>.<random>.part<suffix>`` beside their final
    name (:func:`fastdet.files.atomic.atomic_path`) and renamed when complete;
    a worker that is killed never renames nor deletes its temporary file.
    Called once a video has its final record, when no task writes them.
    """
    for path in paths.files():
        for stale in path.parent.glob(f".{path.stem}.*.part{path.suffix}"):
            with contextlib.suppress(OSError):
                stale.unlink()
    if parts is not None:
        shutil.rmtree(parts, ignore_errors=True)
        folder = Path(parts).parent
        while True:   # the emptied folders up to and including PARTS_FOLDER
            try:
                folder.rmdir()
            except OSError:
                break
            if folder.name == PARTS_FOLDER:
                break
            folder = folder.parent


def remove_replaced(earlier, records, out_dir):
    """Delete the outputs of a video's earlier run that its new run no longer writes.

    A re-run with other outputs (``--no-video``, another ``--format``) would
    otherwise leave the earlier run's annotated video or detections beside
    the new ones, looking current.  Called once the video's new record is
    in the manifest and says done.

    Parameters
    ----------
    earlier : dict or None
        The video's record before this run.
    records : iterable of dict
        Every record of the manifest now, the new one included: an output
        any of them lists is kept.
    out_dir : Path

    Notes
    -----
    Only files the earlier record lists are removed, never one outside
    ``out_dir``, one of the batch's own files, or a symbolic link (whoever
    made it wants its name kept): a manifest may have been edited.
    """
    if not earlier or earlier.get("status") != "done":
        return
    kept = {PurePosixPath(relative) for record in records
            for relative in (record.get("outputs") or {}).values()}
    for relative in (earlier.get("outputs") or {}).values():
        relative = PurePosixPath(relative)
        if (relative in kept or relative.is_absolute() or not relative.parts
                or ".." in relative.parts or relative.parts[0] in BATCH_FILES):
            continue
        path = Path(out_dir) / relative
        if path.is_file() and not path.is_symlink():
            with contextlib.suppress(OSError):
                path.unlink()
