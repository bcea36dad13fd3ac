"""The scaling study of ``fastdet bench --scaling``.

:func:`scaling_study` times fastdet per frame against frame size (640x360 to
3840x2160), number of search scales (the first 1..5 default scales) and
threads; :mod:`.scaling_plot` draws it.
"""

from __future__ import annotations

import dataclasses
import statistics
import time
from dataclasses import dataclass

from ..detector.config import DetectorConfig
from ..detector.detector import Detector
from .timing import fastdet_name, resize_frame, time_fastdet

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
