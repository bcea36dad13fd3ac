"""The annotated video plays in a browser: headless Chromium (Debian's) over HTTP on 127.0.0.1.

A page with a ``<video>`` element loads the file; the test polls it over the
DevTools pipe (``tests/chromium.py``) until the video has played half a
second or failed.  The old MPEG-4 Part 2
(``mp4v``) output is the control: Chromium does not play it.  ``.ci/run``
installs Chromium (``apt-get install chromium``) when it is missing.
"""

from __future__ import annotations

import functools
import http.server
import threading

from chromium import Browser, executable
from video_stubs import BlockDetector

from fastdet.video.pipeline import VideoPipeline
from fastdet.video.run import process_video

PAGE = """<!doctype html><html><body>
<video id="v" muted autoplay playsinline></video><div id="r">pending</div>
<script>
const v = document.getElementById('v'), r = document.getElementById('r');
v.src = location.hash.slice(1);
v.addEventListener('error', () => { r.textContent = 'error ' + (v.error && v.error.code); });
</script></body></html>"""
#: Seconds of real time a page has to start (or refuse) the video: generous, since
#: Chromium on a loaded 2-core machine may take a while; a playing video ends the wait early.
PLAY_WAIT = 30.0


class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass


def playback(folder, name):
    """``(seconds played, width, height, error)`` of ``folder/name`` in headless Chromium.

    Served over HTTP on 127.0.0.1 and polled until the video has played half a
    second or reported an error (a fixed wait was flaky on a loaded machine).
    """
    assert executable(), "Chromium is missing: apt-get install chromium (.ci/run does)"
    (folder / "page.html").write_text(PAGE)
    handler = functools.partial(_QuietHandler, directory=str(folder))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        with Browser() as browser:
            browser.open(f"http://127.0.0.1:{server.server_address[1]}/page.html#{name}")
            browser.wait_for("v.currentTime > 0.5 || v.error !== null", PLAY_WAIT)
            state = browser.evaluate("({time: v.currentTime, width: v.videoWidth, "
                                     "height: v.videoHeight, error: v.error && v.error.code})")
    finally:
        server.shutdown()
        server.server_close()
    return state["time"], state["width"], state["height"], state["error"]


def test_the_annotated_video_plays_in_chromium(data_dir, tmp_path):
    process_video(data_dir / "test_video.mp4", tmp_path / "out.mp4",
                  VideoPipeline(BlockDetector()), end=25)
    played, width, height, error = playback(tmp_path, "out.mp4")
    assert error is None and (width, height) == (1280, 720)
    assert played > 0.5          # 25 frames at 25 fps: it played (most of) its second


def test_the_old_mp4v_output_does_not_play_in_chromium(data_dir, tmp_path):
    process_video(data_dir / "test_video.mp4", tmp_path / "old.mp4",
                  VideoPipeline(BlockDetector()), end=25, codec="mp4v")
    played, width, _, error = playback(tmp_path, "old.mp4")
    assert error == 4 and played == 0 and width == 0    # MEDIA_ERR_SRC_NOT_SUPPORTED
