"""A video's annotated frames through :class:`~fastdet.video.pipeline.VideoPipeline`.

What ``fastdet eval ANNOTATIONS.json VIDEO`` measures: the pipeline runs over
the video from its first frame (so its temporal state -- smoothed heat,
tracks, skipped frames -- is what it would be in ``fastdet run``) up to the
last annotated frame, and the boxes, scores and track ids of the annotated
frames are kept for the detection and tracking metrics.
"""

from __future__ import annotations

from ..errors import InputError
from ..evaluation.annotations import frame_number
from .source import VideoSource


def frame_index(name):
    """The 0-based frame index of an annotated video frame named ``frame<N>``.

    Raises
    ------
    InputError
        For any other name.
    """
    number = frame_number(name)
    if number is None:
        raise InputError(f"video annotations name frames frame<N> (N the 0-based index), "
                         f"got {name!r}")
    return number


def track_annotated_frames(pipeline, video, names):
    """Run the pipeline over a video and keep the frames named in ``names``.

    Parameters
    ----------
    pipeline : VideoPipeline
        Reset before the run.
    video : str or Path
    names : iterable of str
        Annotated frames, ``frame<N>``.

    Returns
    -------
    dict of str to Detections
        Frame name to the pipeline's detections there, with ``track_id``.

    Raises
    ------
    InputError
        When a name is not ``frame<N>`` or the video ends before frame N.
    """
    wanted = {frame_index(name): name for name in names}
    out = {}
    if not wanted:
        return out
    last = max(wanted)
    pipeline.reset()
    needed = pipeline.frames_needed(0)
    with VideoSource(video) as source:
        # Frames between searches are not converted, and mostly not decoded.
        frames = (source.frames(skip=lambda: not pipeline.wants_frame) if needed is None
                  else source.frames(needed=needed))
        for index, frame in enumerate(frames):
            detections = pipeline.process(frame)
            if index in wanted:
                out[wanted[index]] = detections
            if index == last:
                return out
    raise InputError(f"{video} ends before its annotated frame {wanted[last]} "
                     f"({len(out)} of {len(wanted)} annotated frames read)")
