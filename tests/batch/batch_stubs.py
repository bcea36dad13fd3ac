"""Helpers of the batch tests: synthetic clips for the stub detector, clips of the test video."""

from video_stubs import background, paint, texture

#: The stub detector's heat threshold and the heat each of its blobs gets (two windows of 1).
STUB_THRESHOLD, STUB_HEAT = 1.0, 2.0


def two_blocks(count=70, speed=1):
    """B (bottom) from frame 0, A (top) from frame 5, drifting right (B leaves at ~50)."""
    low, high = texture(24, 36, seed=3), texture(22, 30, seed=4)
    frames = []
    for i in range(count):
        frame = background(seed=200 + i)
        paint(frame, (10 + 3 * speed * i, 80, 46 + 3 * speed * i, 104), low)
        if i >= 5:
            paint(frame, (60 + speed * i // 2, 10, 90 + speed * i // 2, 32), high)
        frames.append(frame)
    return frames


def ping_pong(count, length):
    """Frame indices 0..length-1, length-2..1, 0.. repeated up to ``count`` frames."""
    period = 2 * (length - 1)
    return [i % period if i % period < length else period - i % period for i in range(count)]


def looped_clip(source, target, count, codec="mp4v"):
    """``target``: ``count`` frames of ``source`` played forwards and backwards in turn.

    ``codec`` ``"mp4v"`` (OpenCV, quick to write) or ``"h264"`` (PyAV's libx264, what
    dashcams record, with B-frames).
    """
    import av
    import cv2

    from fastdet.video.source import VideoSource

    with VideoSource(source) as reader:
        frames, fps = list(reader), reader.fps
    height, width = frames[0].shape[:2]
    order = ping_pong(count, len(frames))
    if codec == "mp4v":
        writer = cv2.VideoWriter(str(target), cv2.VideoWriter_fourcc(*"mp4v"), fps,
                                 (width, height))
        for index in order:
            writer.write(frames[index])
        writer.release()
        return target
    with av.open(str(target), "w") as container:
        stream = container.add_stream("libx264", rate=round(fps))
        stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
        stream.options = {"preset": "veryfast", "crf": "23"}
        for index in order:
            for packet in stream.encode(av.VideoFrame.from_ndarray(frames[index],
                                                                   format="bgr24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    return target
