"""Studies behind ``fastdet bench``: scaling, the physical floor, HOG vs scikit-image.

* :func:`scaling_study` times fastdet per frame against frame size
  (640x360 to 3840x2160), number of search scales (the first 1..5 default
  scales) and threads;
* :func:`floor_estimate` counts the arithmetic one frame needs (gradient
  votes and window multiply-adds) from the actual scale plans and sets it
  against what one core of this machine does;
* :func:`hog_vs_skimage` times :func:`fastdet.hog` against
  ``skimage.feature.hog`` on the same images.

matplotlib and scikit-image are imported only by the functions that need them
(they live in the ``bench`` extra).
"""

from __future__ import annotations

import dataclasses
import re
import statistics
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from .bench import fastdet_name, resize_frame, time_fastdet
from .config import DetectorConfig
from .detect import Detector

#: Frame sizes of the scaling study, (width, height).
SIZES = ((640, 360), (1280, 720), (1920, 1080), (3840, 2160))


# -- scaling ------------------------------------------------------------------
@dataclass
class ScalingPoint:
    """fastdet's latency at one setting of the scaling study."""

    study: str            # "size" or "scales"
    size: tuple           # (width, height)
    scales: int           # number of search scales used
    threads: int
    median_ms: float
    windows: float        # windows scored per frame
    scaled_pixels: int    # pixels of all resized search regions, one frame
    resize_ms: float = 0.0  # mean resize+convert stage, ms per frame


def scaling_study(frames, model=None, config=None, sizes=SIZES, threads=(1, 2), rounds=3,
                  log=print):
    """Per-frame latency vs frame size, vs number of scales and vs threads.

    Parameters
    ----------
    frames : list of ndarray
        BGR frames; resized to each size of ``sizes``.
    sizes : sequence of (width, height)
    threads : sequence of int
        Thread counts of the size study (the scales study uses one thread).
    rounds : int
        Passes over all settings; each pass times every frame once per
        setting, and a setting's figure is the median over passes of its
        median per frame.

    Returns
    -------
    list of ScalingPoint

    Notes
    -----
    Settings are visited round-robin, so a burst of load from elsewhere on
    a shared machine hits one pass of every setting rather than all passes
    of one.  Within a pass the one-thread settings run first, and a short
    pause follows every multi-thread setting: an OpenMP thread pool spins
    for a while after its last parallel region and would slow a one-thread
    run right after it.
    """
    config = config or DetectorConfig()
    base = (1280, 720)
    settings = []  # (study, size, threads, scale count, config)
    for count in range(1, len(config.search.scales) + 1):
        search = dataclasses.replace(config.search, scales=config.search.scales[:count])
        settings.append(("scales", base, 1, count, dataclasses.replace(config, search=search)))
    for count in sorted(threads):
        for size in sizes:
            settings.append(("size", tuple(size), count, len(config.search.scales), config))
    resized = {size: [resize_frame(frame, size) for frame in frames]
               for size in {setting[1] for setting in settings}}
    medians = {index: [] for index in range(len(settings))}
    results = {}
    for round_index in range(rounds):
        log(f"scaling: pass {round_index + 1} of {rounds} over {len(settings)} settings ...")
        for index, (_, size, count, _, setting_config) in enumerate(settings):
            detector = Detector(model=model, config=setting_config, threads=count)
            result = time_fastdet(detector, resized[size], repeat=1)
            medians[index].append(result.median_ms)
            results[index] = (detector, result)
            if detector.threads > 1:
                time.sleep(0.2)
    points = []
    for index, (study, size, _, _, _) in enumerate(settings):
        detector, result = results[index]
        plans = detector.plans(size)
        points.append(ScalingPoint(study, size, len(plans), detector.threads,
                                   statistics.median(medians[index]), result.windows_per_frame,
                                   scaled_pixels(plans), result.stages.get("resize_convert", 0.0)))
    return points


def scaled_pixels(plans):
    """Pixels of every resized search region of one frame."""
    return int(sum(plan.scaled_size[0] * plan.scaled_size[1] for plan in plans))


def format_scaling(points):
    """Two markdown tables: latency vs frame size x threads, and vs number of scales."""
    sizes = sorted({p.size for p in points if p.study == "size"}, key=lambda s: s[0] * s[1])
    threads = sorted({p.threads for p in points if p.study == "size"})
    lookup = {(p.size, p.threads): p for p in points if p.study == "size"}
    lines = ["| frame size | frame Mpx | scaled Mpx/frame | windows/frame | "
             + " | ".join(f"{fastdet_name(t)} ms" for t in threads)
             + " | of which resize+convert (1 thread) |",
             "|---|---:|---:|---:|" + "---:|" * len(threads) + "---:|"]
    for size in sizes:
        first = lookup[(size, threads[0])]
        cells = " | ".join(f"{lookup[(size, t)].median_ms:.1f}" for t in threads)
        lines.append(f"| {size[0]}x{size[1]} | {size[0] * size[1] / 1e6:.2f} "
                     f"| {first.scaled_pixels / 1e6:.2f} | {first.windows:.0f} | {cells} "
                     f"| {first.resize_ms:.1f} |")
    lines += ["", "| scales (1280x720, 1 thread) | scaled Mpx/frame | windows/frame | ms |",
              "|---|---:|---:|---:|"]
    for p in (p for p in points if p.study == "scales"):
        lines.append(f"| first {p.scales} | {p.scaled_pixels / 1e6:.2f} | {p.windows:.0f} "
                     f"| {p.median_ms:.1f} |")
    return "\n".join(lines)


def plot_scaling(points, path):
    """Write the scaling study as a PNG (matplotlib, headless); returns the path."""
    import matplotlib

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


# -- the physical floor ---------------------------------------------------------
def clock_hz():
    """Nominal clock of this machine's cores (from /proc/cpuinfo), or None."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return None
    nominal = re.search(r"model name\s*:.*@\s*([\d.]+)\s*GHz", text)
    if nominal:
        return float(nominal.group(1)) * 1e9
    current = re.search(r"cpu MHz\s*:\s*([\d.]+)", text)
    return float(current.group(1)) * 1e6 if current else None


def measured_mac_rate(length, seconds=0.3):
    """Multiply-adds per second one core sustains in float32 matrix products.

    A single-threaded BLAS ``sgemm`` of windows x features by features x 64
    is the best a core does on dense dot products of this length (cache
    blocked, fully vectorised): the ceiling for window scoring.
    """
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - scikit-learn depends on it
        threadpool_limits = None
    rng = np.random.default_rng(0)
    a = rng.random((256, length), dtype=np.float32)
    b = rng.random((length, 64), dtype=np.float32)
    samples = []

    def run():
        a @ b  # warm-up: pages and BLAS set-up
        deadline = time.perf_counter() + seconds
        while time.perf_counter() < deadline or len(samples) < 3:
            start = time.perf_counter()
            a @ b
            samples.append(time.perf_counter() - start)

    if threadpool_limits is None:
        run()
    else:
        with threadpool_limits(limits=1):
            run()
    return a.shape[0] * length * b.shape[1] / min(samples)


def floor_estimate(plans, model, fastdet_ms=None, channels=None):
    """Arithmetic one frame needs, and the time one core needs for it at best.

    Counts, from the frame's actual scale plans:

    * gradient votes: every pixel of every resized region, per HOG channel,
      gets a gradient, a magnitude and one histogram vote;
    * scoring multiply-adds: every window's feature vector (the model's full
      length) dotted with the weights.

    One core's rates: one histogram vote per cycle (a load-add-store into a
    small table; stores issue once per cycle, so votes do not vectorise),
    and the measured single-thread float32 ``sgemm`` rate for multiply-adds.

    Returns
    -------
    dict
        ``votes``, ``macs``, ``clock_hz``, ``mac_rate``, ``vote_ms``,
        ``mac_ms``, ``floor_ms`` and, given ``fastdet_ms``, ``distance`` (how
        many times the floor fastdet takes).
    """
    if channels is None:
        channels = model.layout.hog_channels
    windows = sum(plan.n_windows for plan in plans)
    votes = scaled_pixels(plans) * channels
    macs = windows * model.layout.length
    clock = clock_hz() or 2.5e9
    mac_rate = measured_mac_rate(model.layout.length)
    estimate = {"windows": windows, "scaled_pixels": scaled_pixels(plans), "channels": channels,
                "feature_length": model.layout.length, "votes": votes, "macs": macs,
                "clock_hz": clock, "mac_rate": mac_rate, "vote_ms": votes / clock * 1e3,
                "mac_ms": macs / mac_rate * 1e3}
    estimate["floor_ms"] = estimate["vote_ms"] + estimate["mac_ms"]
    if fastdet_ms:
        estimate["fastdet_ms"] = fastdet_ms
        estimate["distance"] = fastdet_ms / estimate["floor_ms"]
    return estimate


def format_floor(estimate):
    """The floor estimate as a few lines of markdown."""
    e = estimate
    lines = [
        f"- gradient votes: {e['scaled_pixels'] / 1e6:.2f} M scaled pixels x {e['channels']} "
        f"channels = {e['votes'] / 1e6:.2f} M votes; at 1 vote/cycle and "
        f"{e['clock_hz'] / 1e9:.2f} GHz: {e['vote_ms']:.2f} ms",
        f"- window scoring: {e['windows']} windows x {e['feature_length']} features = "
        f"{e['macs'] / 1e6:.2f} M multiply-adds; at this core's measured single-thread sgemm "
        f"rate ({e['mac_rate'] / 1e9:.1f} G MAC/s): {e['mac_ms']:.2f} ms",
        f"- floor: {e['floor_ms']:.2f} ms per frame on one core",
    ]
    if "distance" in e:
        lines.append(f"- fastdet 1 thread: {e['fastdet_ms']:.2f} ms = {e['distance']:.0f}x "
                     "the floor")
    return "\n".join(lines)


# -- fastdet.hog vs scikit-image ------------------------------------------------
@dataclass
class HogComparison:
    size: tuple
    fastdet_ms: float
    skimage_ms: float

    @property
    def speedup(self):
        return self.skimage_ms / self.fastdet_ms


def _median_seconds(function, repeat):
    function()  # warm-up (compilation, caches) untimed
    samples = []
    for _ in range(repeat):
        start = time.perf_counter()
        function()
        samples.append(time.perf_counter() - start)
    return statistics.median(samples)


def hog_vs_skimage(frame, sizes=((1280, 720),), repeat=5, skimage_repeat=3,
                   cells_per_block=(2, 2), log=print):
    """Time ``fastdet.hog`` and ``skimage.feature.hog`` on the grey frame at each size.

    Both run with the same arguments (9 orientations, 8x8 cells, 2x2 blocks,
    L2-Hys) on the same uint8 image, one after the other, one thread.
    """
    from skimage.feature import hog as skimage_hog

    from .hog_api import hog

    rows = []
    for size in sizes:
        grey = cv2.cvtColor(resize_frame(frame, size), cv2.COLOR_BGR2GRAY)
        log(f"hog vs skimage at {size[0]}x{size[1]} ...")
        ours = _median_seconds(
            lambda image=grey: hog(image, cells_per_block=cells_per_block), repeat)
        theirs = _median_seconds(
            lambda image=grey: skimage_hog(image, cells_per_block=cells_per_block),
            skimage_repeat)
        rows.append(HogComparison(tuple(size), ours * 1e3, theirs * 1e3))
    return rows


def format_hog(rows):
    lines = ["| image (grey uint8) | fastdet.hog ms | skimage.feature.hog ms | x faster |",
             "|---|---:|---:|---:|"]
    for row in rows:
        lines.append(f"| {row.size[0]}x{row.size[1]} | {row.fastdet_ms:.2f} "
                     f"| {row.skimage_ms:.1f} | {row.speedup:.0f}x |")
    return "\n".join(lines)
