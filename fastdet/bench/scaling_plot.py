"""The plot of the scaling study (``fastdet bench --plot``); needs matplotlib (``viz`` extra)."""

from __future__ import annotations

from pathlib import Path

from ..errors import MissingExtraError
from .timing import fastdet_name

try:
    import matplotlib
except ImportError as exc:  # pragma: no cover - the viz extra is part of the test extra
    raise MissingExtraError("matplotlib is needed for --plot: pip install 'fastdet[viz]'") from exc


def plot_scaling(points, path):
    """Write the scaling study as a PNG (matplotlib, headless); returns the path."""
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    size_points = [p for p in points if p.study == "size"]
    scale_points = [p for p in points if p.study == "scales"]
    figure, (by_size, by_scales) = plt.subplots(1, 2, figsize=(11, 4.2))
    sizes = sorted({p.size for p in size_points}, key=lambda s: s[0] * s[1])
    megapixels = [w * h / 1e6 for w, h in sizes]
    for count in sorted({p.threads for p in size_points}):
        chosen = sorted((p for p in size_points if p.threads == count),
                        key=lambda p: p.size[0] * p.size[1])
        by_size.plot([p.size[0] * p.size[1] / 1e6 for p in chosen],
                     [p.median_ms for p in chosen], marker="o", label=fastdet_name(count))
    one = sorted((p for p in size_points if p.threads == 1), key=lambda p: p.size[0] * p.size[1])
    if one:
        by_size.plot([p.size[0] * p.size[1] / 1e6 for p in one], [p.resize_ms for p in one],
                     linestyle="--", marker=".", color="tab:gray",
                     label="of which resize+convert (1 thread)")
    by_size.set_xticks(megapixels)
    by_size.set_xticklabels([f"{w}x{h}" for w, h in sizes], rotation=20, fontsize=8)
    by_size.set_xlabel("frame size (x axis: megapixels)")
    by_size.set_ylabel("ms per frame (median)")
    by_size.set_ylim(bottom=0)
    by_size.set_title("latency vs frame size and threads")
    by_size.legend(fontsize=8)
    by_size.grid(True, alpha=0.3)
    by_scales.plot([p.scales for p in scale_points], [p.median_ms for p in scale_points],
                   marker="o", label="ms per frame")
    by_scales.set_xlabel("number of search scales (first n defaults), 1280x720, 1 thread")
    by_scales.set_ylabel("ms per frame (median)")
    by_scales.set_xticks([p.scales for p in scale_points])
    by_scales.set_ylim(bottom=0)
    twin = by_scales.twinx()
    twin.plot([p.scales for p in scale_points], [p.windows for p in scale_points],
              color="tab:gray", linestyle="--", marker="x", label="windows per frame")
    twin.set_ylabel("windows per frame (dashed)")
    twin.set_ylim(bottom=0)
    by_scales.set_title("latency vs number of scales")
    by_scales.grid(True, alpha=0.3)
    figure.tight_layout()
    path = Path(path)
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path
