"""The annotated video plays in a browser: headless Chromium (Debian's) over HTTP on 127.0.0.1.

A page with a ``<video>`` element loads the file and reports, after a few
seconds of (virtual) time, how far playback got.  The old MPEG-4 Part 2
(``mp4v``) output is the control: Chromium does not play it.  ``.ci/run``
installs Chromium (``apt-get install chromium``) when it is missing.
"""

from __future__ import annotations

import functools
import http.server
import re
import shutil
import subprocess
import threading

from video_stubs import BlockDetector

from fastdet.video.pipeline import VideoPipeline
from fastdet.video.run import process_video

PAGE = """<!doctype html><html><body>
<video id="v" muted autoplay playsinline></video><div id="r">pending</div>
<script>
const v = document.getElementById('v'), r = document.getElementById('r');
v.src = location.hash.slice(1);
v.addEventListener('error', () => { r.textContent = 'error ' + (v.error && v.error.code); });
setTimeout(() => { r.textContent = 'time=' + v.currentTime.toFixed(3) + ' size=' +
  v.videoWidth + 'x' + v.videoHeight; }, 2500);
</script></body></html>"""


class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass


def playback(folder, name, profile):
    """``(seconds played, width, height)`` of ``folder/name`` in headless Chromium."""
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    assert chromium, "Chromium is missing: apt-get install chromium (.ci/run does)"
    (folder / "page.html").write_text(PAGE)
    handler = functools.partial(_QuietHandler, directory=str(folder))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        url = f"http://127.0.0.1:{server.server_address[1]}/page.html#{name}"
        page = subprocess.run(
            [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
             "--no-first-run", "--disable-background-networking", "--disable-component-update",
             "--disable-sync", f"--user-data-dir={profile}",
             "--autoplay-policy=no-user-gesture-required", "--virtual-time-budget=4000",
             "--dump-dom", url], capture_output=True, text=True, timeout=90).stdout
    finally:
        server.shutdown()
        server.server_close()
    match = re.search(r'<div id="r">time=([\d.]+) size=(\d+)x(\d+)', page)
    assert match, f"the page did not report: {page[-300:]!r}"
    return float(match[1]), int(match[2]), int(match[3])


def test_the_annotated_video_plays_in_chromium(data_dir, tmp_path):
    process_video(data_dir / "test_video.mp4", tmp_path / "out.mp4",
                  VideoPipeline(BlockDetector()), end=25)
    played, width, height = playback(tmp_path, "out.mp4", tmp_path / "profile-h264")
    assert (width, height) == (1280, 720)
    assert played > 0.5          # 25 frames at 25 fps: it played (most of) its second


def test_the_old_mp4v_output_does_not_play_in_chromium(data_dir, tmp_path):
    process_video(data_dir / "test_video.mp4", tmp_path / "old.mp4",
                  VideoPipeline(BlockDetector()), end=25, codec="mp4v")
    played, width, _ = playback(tmp_path, "old.mp4", tmp_path / "profile-mp4v")
    assert played == 0 and width == 0
