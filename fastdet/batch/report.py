"""What a batch tells its user: the summary table, and ``DIR/index.html``.

The page lists every video of the manifest with its thumbnail, frames,
vehicles, frame rate and status, and the annotated video playing inline (each
starts when it scrolls into view).  Every text taken from the manifest (file
names, reasons) is HTML-escaped and every link URL-quoted, so a file named
``<script>.mp4`` stays a name.  A file name that is not UTF-8 is shown with
its odd bytes as ``\\xff`` (:func:`~fastdet.batch.inputs.display_name`) and
linked by its bytes (``%FF``), so its link finds the file.  The summary table
shows a name's control characters (a newline, ESC) as escapes (``\\n``,
``\\x1b``), which a terminal prints rather than acts on.
"""

from __future__ import annotations

import html
import os
import re
from pathlib import Path
from urllib.parse import quote

from ..files.atomic import atomic_path
from .inputs import display_name

REPORT_NAME = "index.html"

_STYLE = """
body { font: 15px/1.4 system-ui, sans-serif; margin: 2em; color: #222; }
h1 { font-size: 1.4em; }
.videos { display: grid; grid-template-columns: repeat(auto-fill, minmax(340px, 1fr)); gap: 1.2em; }
.video { border: 1px solid #ccc; border-radius: 6px; padding: 0.8em; }
.video h2 { font-size: 1em; margin: 0 0 0.5em; word-break: break-all; }
.video video, .video > img { width: 100%; background: #000; }
.video .thumbnail { width: auto; }
.video table { border-collapse: collapse; margin-top: 0.4em; }
.video td { padding: 0 1em 0 0; }
.failed { border-color: #c33; background: #fff4f4; }
.reason { color: #a00; }
"""

#: Plays a video while it is on screen (muted, so browsers allow it without a click).
_SCRIPT = """
const watcher = new IntersectionObserver(entries => {
  for (const entry of entries) {
    if (entry.isIntersecting) entry.target.play().catch(() => {});
    else entry.target.pause();
  }
});
document.querySelectorAll("video").forEach(video => watcher.observe(video));
"""


#: C0 and C1 control characters: a terminal acts on them (a newline broke the table's row,
#: ESC [31m turned the terminal red).
_CONTROL = re.compile("[\x00-\x1f\x7f-\x9f]")


def _printable(text):
    """:func:`~fastdet.batch.inputs.display_name` of ``text`` with each control character
    as its escape (``\\n``, ``\\x1b``), for the table printed on a terminal."""
    return _CONTROL.sub(lambda match: match.group().encode("unicode_escape").decode("ascii"),
                        display_name(text))


def _cell(value, digits=0):
    if value is None:
        return "-"
    return f"{value:.{digits}f}" if isinstance(value, float) else str(value)


def summary_table(records, skipped=(), wall=None):
    """The table printed at the end of a batch, with a totals line and the reasons of failures.

    Parameters
    ----------
    records : list of dict
        Manifest records of the batch's videos.
    skipped : collection of str
        Relative paths of the videos that were already done.
    wall : float, optional
        Seconds the batch took (for its aggregate frame rate).

    Returns
    -------
    str
    """
    width = max([len("video")] + [len(_printable(r["relative"])) for r in records])
    lines = [f"{'video':<{width}}  {'status':<7} {'frames':>7} {'vehicles':>8} {'fps':>7} "
             f"{'seconds':>8}"]
    for record in records:
        status = "skipped" if record["relative"] in skipped else record["status"]
        lines.append(f"{_printable(record['relative']):<{width}}  {status:<7} "
                     f"{_cell(record.get('frames')):>7} {_cell(record.get('vehicles')):>8} "
                     f"{_cell(record.get('fps'), 1):>7} {_cell(record.get('seconds'), 1):>8}")
    done = [r for r in records if r["status"] == "done" and r["relative"] not in skipped]
    failed = [r for r in records if r["status"] == "failed"]
    frames = sum(r.get("frames") or 0 for r in done)
    totals = (f"{len(records)} videos: {len(done)} done, {len(skipped)} already done, "
              f"{len(failed)} failed; {frames} frames")
    if wall:
        totals += f" in {wall:.1f} s ({frames / wall:.1f} fps over the batch)"
    lines.append(totals)
    lines += [f"failed: {_printable(r['relative'])}: {_printable(r.get('reason', ''))}"
              for r in failed]
    return "\n".join(lines)


def _link(relative):
    """The URL of an output, relative to the page: the bytes of its name, quoted."""
    try:
        return quote(os.fsencode(relative))
    except UnicodeEncodeError:   # a surrogate no file name decodes to (an edited manifest)
        return quote(display_name(relative))


def _article(record):
    name = html.escape(display_name(record["relative"]))
    outputs = record.get("outputs") or {}
    status = record["status"]
    parts = [f'<article class="video {html.escape(status)}" data-relative="{name}">',
             f"<h2>{name}</h2>"]
    thumbnail = outputs.get("thumbnail")
    poster = f' poster="{_link(thumbnail)}"' if thumbnail else ""
    if status == "done" and outputs.get("video"):
        parts.append(f'<video src="{_link(outputs["video"])}"{poster} muted loop playsinline '
                     f'controls preload="metadata"></video>')
    elif thumbnail:
        parts.append(f'<img src="{_link(thumbnail)}" alt="{name}">')
    rows = [("status", html.escape(status)), ("frames", _cell(record.get("frames"))),
            ("vehicles", _cell(record.get("vehicles"))), ("fps", _cell(record.get("fps"), 1))]
    if thumbnail and status == "done":
        rows.append(("thumbnail", f'<img class="thumbnail" src="{_link(thumbnail)}" alt="" '
                                  f'height="36">'))
    if outputs.get("detections"):
        detections = outputs["detections"]
        rows.append(("detections", f'<a href="{_link(detections)}">'
                                   f'{html.escape(display_name(Path(detections).name))}</a>'))
    parts.append("<table>" + "".join(f"<tr><td>{key}</td><td>{value}</td></tr>"
                                     for key, value in rows) + "</table>")
    if status == "failed":
        reason = html.escape(display_name(record.get("reason", "")))
        parts.append(f'<p class="reason">{reason}</p>')
    parts.append("</article>")
    return "\n".join(parts)


def write_report(out_dir, records):
    """Write ``out_dir/index.html`` listing ``records`` (atomically); returns its path."""
    path = Path(out_dir) / REPORT_NAME
    done = sum(r["status"] == "done" for r in records)
    body = "\n".join(_article(r) for r in records)
    page = (f'<!doctype html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
            f"<title>fastdet batch: {len(records)} videos</title>\n<style>{_STYLE}</style>\n"
            f"</head>\n<body>\n<h1>fastdet batch: {len(records)} videos, {done} done, "
            f"{len(records) - done} failed</h1>\n<div class=\"videos\">\n{body}\n</div>\n"
            f"<script>{_SCRIPT}</script>\n</body>\n</html>\n")
    with atomic_path(path) as tmp:
        tmp.write_text(page, encoding="utf-8")
    return path
