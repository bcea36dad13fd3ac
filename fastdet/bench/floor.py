"""The physical floor of one frame: the arithmetic it needs against what one core does.

:func:`floor_estimate` counts gradient votes and window multiply-adds from the
actual scale plans and sets them against the clock this core runs at and its
``sgemm`` rate, both measured.
"""

from __future__ import annotations

import re
import time
from pathlib import Path

import numpy as np

from .scaling import scaled_pixels


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


def measured_clock_hz(seconds=0.2, steps=2_000_000):
    """The clock one core runs at now: cycles of a chain of dependent integer
    operations per second (:mod:`fastdet.kernels.clock`), the fastest of the runs."""
    from ..kernels.clock import CYCLES_PER_STEP, integer_chain

    integer_chain(1, 1)  # loaded (or compiled) before timing
    samples = []
    deadline = time.perf_counter() + seconds
    while time.perf_counter() < deadline or len(samples) < 3:
        start = time.perf_counter()
        integer_chain(steps, len(samples))
        samples.append(time.perf_counter() - start)
    return steps * CYCLES_PER_STEP / min(samples)


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
    small table; stores issue once per cycle, so votes do not vectorise) at
    the clock the core runs at (:func:`measured_clock_hz`; cores boost above
    the nominal clock), and the measured single-thread float32 ``sgemm``
    rate for multiply-adds.

    Returns
    -------
    dict
        ``votes``, ``macs``, ``clock_hz`` (measured), ``nominal_hz`` (from
        ``/proc/cpuinfo``, or None), ``mac_rate``, ``vote_ms``, ``mac_ms``,
        ``floor_ms`` and, given ``fastdet_ms``, ``distance`` (how many times
        the floor fastdet takes).
    """
    if channels is None:
        channels = model.layout.hog_channels
    windows = sum(plan.n_windows for plan in plans)
    votes = scaled_pixels(plans) * channels
    macs = windows * model.layout.length
    clock = measured_clock_hz()
    mac_rate = measured_mac_rate(model.layout.length)
    estimate = {"windows": windows, "scaled_pixels": scaled_pixels(plans), "channels": channels,
                "feature_length": model.layout.length, "votes": votes, "macs": macs,
                "clock_hz": clock, "nominal_hz": clock_hz(), "mac_rate": mac_rate,
                "vote_ms": votes / clock * 1e3,
                "mac_ms": macs / mac_rate * 1e3}
    estimate["floor_ms"] = estimate["vote_ms"] + estimate["mac_ms"]
    if fastdet_ms:
        estimate["fastdet_ms"] = fastdet_ms
        estimate["distance"] = fastdet_ms / estimate["floor_ms"]
    return estimate


def format_floor(estimate):
    """The floor estimate as a few lines of markdown."""
    e = estimate
    nominal = (f"; nominal {e['nominal_hz'] / 1e9:.2f} GHz" if e.get("nominal_hz") else "")
    lines = [
        f"- gradient votes: {e['scaled_pixels'] / 1e6:.2f} M scaled pixels x {e['channels']} "
        f"channels = {e['votes'] / 1e6:.2f} M votes; at 1 vote/cycle and "
        f"{e['clock_hz'] / 1e9:.2f} GHz (the clock this core runs at, measured{nominal}): "
        f"{e['vote_ms']:.2f} ms",
        f"- window scoring: {e['windows']} windows x {e['feature_length']} features = "
        f"{e['macs'] / 1e6:.2f} M multiply-adds; at this core's measured single-thread sgemm "
        f"rate ({e['mac_rate'] / 1e9:.1f} G MAC/s): {e['mac_ms']:.2f} ms",
        f"- floor: {e['floor_ms']:.2f} ms per frame on one core",
    ]
    if "distance" in e:
        lines.append(f"- fastdet 1 thread: {e['fastdet_ms']:.2f} ms = {e['distance']:.1f}x "
                     "the floor")
    return "\n".join(lines)
