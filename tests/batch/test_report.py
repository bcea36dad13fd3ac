"""The summary table, and DIR/index.html: escaped, and working in a real browser."""

from html.parser import HTMLParser

import av
import cv2
import numpy as np
from chromium import Browser, executable

from fastdet.batch.report import summary_table, write_report

NASTY = 'day1/<script>alert("x")</script> & \'q\'.mp4'


def record(relative, status="done", frames=38, **values):
    stem = relative.rsplit(".", 1)[0]
    base = {"relative": relative, "status": status}
    if status == "done":
        base.update(frames=frames, vehicles=2, fps=21.5, seconds=1.77,
                    outputs={"video": f"{stem}.mp4", "detections": f"{stem}.jsonl",
                             "thumbnail": f"{stem}.jpg"})
    return {**base, **values}


def test_summary_table():
    records = [record("a.mp4"), record("sub/long name.mp4", frames=1000),
               record("broken.mp4", "failed", reason="cannot read broken.mp4 as a video")]
    table = summary_table(records, skipped={"a.mp4"}, wall=50.0).splitlines()
    assert table[0].split() == ["video", "status", "frames", "vehicles", "fps", "seconds"]
    assert table[1].split() == ["a.mp4", "skipped", "38", "2", "21.5", "1.8"]
    assert table[3].split() == ["broken.mp4", "failed", "-", "-", "-", "-"]
    assert table[4] == ("3 videos: 1 done, 1 already done, 1 failed; 1000 frames in 50.0 s "
                        "(20.0 fps over the batch)")
    assert table[5] == "failed: broken.mp4: cannot read broken.mp4 as a video"


class _Page(HTMLParser):
    """Elements and text of a page, as a browser's parser sees them."""

    def __init__(self):
        super().__init__()
        self.tags, self.articles, self.text = [], [], []

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        self.tags.append((tag, attrs))
        if tag == "article":
            self.articles.append(attrs["data-relative"])

    def handle_data(self, data):
        self.text.append(data)


def test_every_video_is_listed_and_every_text_escaped(tmp_path):
    records = [record("a.mp4"), record(NASTY),
               record("bad.mp4", "failed", reason="<img src=x onerror=alert(1)> corrupt")]
    page = _Page()
    page.feed(write_report(tmp_path, records).read_text(encoding="utf-8"))
    assert page.articles == ["a.mp4", NASTY, "bad.mp4"]
    assert [t for t, _ in page.tags].count("script") == 1        # the page's own
    assert [a.get("src") for t, a in page.tags if t == "img"].count("x") == 0
    assert NASTY in "".join(page.text)
    assert "<img src=x onerror=alert(1)> corrupt" in "".join(page.text)
    sources = [a["src"] for t, a in page.tags if t == "video"]
    assert sources == ["a.mp4", "day1/%3Cscript%3Ealert%28%22x%22%29%3C/script%3E%20%26%20%27q%27.mp4"]


def h264_clip(path, frames=50, size=(320, 180)):
    """A small H.264 video browsers play (a bar sweeping across)."""
    with av.open(str(path), "w") as container:
        stream = container.add_stream("libx264", rate=25)
        stream.width, stream.height, stream.pix_fmt = size[0], size[1], "yuv420p"
        for i in range(frames):
            frame = np.full((size[1], size[0], 3), 40, np.uint8)
            frame[:, (6 * i) % size[0]:(6 * i) % size[0] + 12] = (0, 0, 255)
            for packet in stream.encode(av.VideoFrame.from_ndarray(frame, format="bgr24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)


def playing_state(browser):
    return browser.evaluate("""(() => {
        const video = document.querySelector("video");
        return {time: video.currentTime, paused: video.paused, error: video.error && video.error.code,
                articles: [...document.querySelectorAll("article")].map(a => a.dataset.relative),
                thumbnails: [...document.querySelectorAll("img.thumbnail")].map(
                    i => i.complete && i.naturalWidth > 0)};
    })()""")


def test_the_page_works_in_headless_chromium(tmp_path):
    assert executable(), "Chromium is missing: apt-get install chromium (.ci/run does)"
    records = [record("a.mp4"), record(NASTY), record("bad.mp4", "failed", reason="corrupt")]
    for rec in records[:2]:
        stem = rec["relative"].rsplit(".", 1)[0]
        (tmp_path / stem).parent.mkdir(parents=True, exist_ok=True)
        h264_clip(tmp_path / f"{stem}.mp4")
        cv2.imwrite(str(tmp_path / f"{stem}.jpg"), np.full((90, 160, 3), 200, np.uint8))
    page = write_report(tmp_path, records)
    with Browser() as browser:
        browser.open(page.as_uri())
        # Nothing but the page's own script ran: the file name stayed text.
        assert browser.evaluate("document.scripts.length") == 1
        assert browser.wait_for("document.querySelector('video').currentTime > 0.2")
        state = playing_state(browser)
    assert state["articles"] == ["a.mp4", NASTY, "bad.mp4"]
    assert state["thumbnails"] == [True, True]
    assert state["error"] is None and not state["paused"]


def test_summary_table_escapes_control_characters_of_names_and_reasons():
    """A video named ``new<LF>line.mp4`` broke its row in two; ``ESC[31m`` in a name
    turned the terminal red."""
    records = [{"relative": "new\nline.mp4", "status": "done", "frames": 4},
               {"relative": "esc\x1b[31mred.mp4", "status": "failed",
                "reason": "bad\rframe\x85"}]
    lines = summary_table(records).splitlines()
    assert len(lines) == 5
    assert lines[1].split()[:2] == ["new\\nline.mp4", "done"]
    assert lines[2].split()[:2] == ["esc\\x1b[31mred.mp4", "failed"]
    assert lines[4] == "failed: esc\\x1b[31mred.mp4: bad\\rframe\\x85"
