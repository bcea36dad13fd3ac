"""Where one video's outputs go under the output folder, and the litter of killed attempts.

For an input whose relative path is ``day1/clip.mp4`` the outputs are
``DIR/day1/clip.mp4`` (annotated video), ``DIR/day1/clip.jsonl`` (or ``.csv``,
``.txt`` for MOT) and ``DIR/day1/clip.jpg`` (thumbnail of the report page).
Segments of a long video are written to ``DIR/.fastdet-parts/day1/clip/``
and merged; the folder is removed when the video is done.
"""

from __future__ import annotations

import contextlib
import shutil
from dataclasses import dataclass
from pathlib import Path

from ..errors import InputError

#: Hidden folder (folder searches skip it) for the segments of long videos.
PARTS_FOLDER = ".fastdet-parts"


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
        When an output would overwrite the input video itself.
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
    return paths


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
