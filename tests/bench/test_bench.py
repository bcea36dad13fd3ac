"""``fastdet bench`` and its helpers: same-frame ratios, peer settings, tables, CLI."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fastdet.bench.floor import floor_estimate, format_floor
from fastdet.bench.latency import (BenchmarkRun, format_stages, format_table, format_threads,
                                   run_benchmark)
from fastdet.bench.peers import native_search
from fastdet.bench.scaling import ScalingPoint, format_scaling
from fastdet.bench.scaling_plot import plot_scaling
from fastdet.bench.timing import PipelineResult, speedup, spread_indices
from fastdet.cli.app import EXIT_ERROR, main
from fastdet.detector.config import DetectorConfig
from fastdet.detector.detector import Detector
from fastdet.detector.features import FeatureLayout, FeatureOptions
from fastdet.detector.model import Model
from fastdet.detector.plan import plan_scales
from fastdet.detector.scoring import STAGES


@pytest.fixture(scope="module")
def model():
    options = FeatureOptions()
    rng = np.random.default_rng(3)
    weights = rng.normal(scale=0.01, size=FeatureLayout(options).length).astype(np.float32)
    return Model(weights=weights, bias=0.0, options=options)


@pytest.fixture(scope="module")
def model_path(model, tmp_path_factory):
    path = tmp_path_factory.mktemp("model") / "random.npz"
    model.save(path)
    return path


def result(name, seconds, indices=None, stages=None):
    indices = list(range(len(seconds))) if indices is None else indices
    return PipelineResult(name, list(seconds), indices, 100.0, stages or {})


def test_speedup_compares_only_the_frames_both_timed():
    fast = result("fastdet 1 thread", [0.01, 0.01, 0.02, 0.04, 0.01])
    # The slow peer timed frames 1 and 3 only: fastdet's 10 ms and 40 ms there.
    slow = result("reference", [1.0, 4.0], indices=[1, 3])
    assert speedup(slow, fast) == pytest.approx(2.5 / 0.025)
    assert math.isnan(speedup(None, fast))
    assert math.isnan(speedup(result("x", [1.0], [9]), fast))


def test_spread_indices_cover_the_video():
    assert spread_indices(38, 5) == [0, 9, 18, 28, 37]
    assert spread_indices(3, 5) == [0, 1, 2]
    assert spread_indices(10, 0) == []


def test_native_search_spans_fastdet_window_sizes(model):
    plans = plan_scales(DetectorConfig(), model.options, (1280, 720))
    native = native_search(plans)
    assert native["nlevels"] == len(plans) == 5
    # Smallest window (32 px) becomes OpenCV's 64; the top level reaches 128 px.
    assert native["upscale"] == pytest.approx(2.0, rel=0.01)
    assert 32 * native["scale"] ** 4 == pytest.approx(128, rel=0.02)
    assert native["region"] == [min(p.roi[0] for p in plans), min(p.roi[1] for p in plans),
                                max(p.roi[2] for p in plans), max(p.roi[3] for p in plans)]


def test_tables_show_ratios_and_stage_split():
    stages = {stage: 1.0 for stage in STAGES}
    stages["total"] = 10.0
    fast = result("fastdet 1 thread", [0.02, 0.02, 0.02], stages=stages)
    reference = result("reference", [2.0], indices=[1])
    opencv = result("opencv same windows, 1 thread", [0.04, 0.04, 0.04])
    table = format_table(BenchmarkRun([fast, reference, opencv], 3, (1280, 720), ()))
    fast_row = next(line for line in table.splitlines() if line.startswith("| fastdet"))
    assert "| 100.0x | 2.0x |" in fast_row
    split = format_stages([fast, reference])
    assert "python overhead" in split and "labelling" in split
    assert "| fastdet 1 thread | 1.00 | 1.00 | 1.00 | 1.00 | 1.00 | 1.00 | 4.00 | 10.00 |" in split


def test_threads_table_shows_each_thread_and_both_speed_ups():
    one = PipelineResult("fastdet 1 thread", [0.004] * 3, [0, 1, 2], 100.0, {"total": 4.0},
                         [3.8], [3.6], 3.9)
    two = PipelineResult("fastdet 2 threads", [0.0025] * 3, [0, 1, 2], 100.0, {"total": 2.5},
                         [2.0, 1.9], [1.8, 1.8], 2.1)
    rows = format_threads([one, two]).splitlines()
    assert rows[2] == "| fastdet 1 thread | 4.00 | 3.80 | 3.60 | 5% | 1.0x | 3.90 | 1.0x |"
    assert rows[3] == ("| fastdet 2 threads | 2.50 | 2.00 / 1.90 | 1.80 / 1.80 | 22% | 1.6x "
                       "| 2.10 | 1.9x |")
    assert format_threads([result("reference", [2.0])]) == ""


def test_missing_opencv_peer_is_a_note_not_a_failure(model, monkeypatch, tmp_path):
    monkeypatch.setenv("FASTDET_OPENCV_PEER", str(tmp_path / "no-such-venv"))
    frames = [np.zeros((180, 320, 3), np.uint8)] * 2
    run = run_benchmark(frames, threads=(1,), repeat=1, reference_frames=0, opencv=True,
                        model=model, log=lambda line: None)
    assert [r.name for r in run.results] == ["fastdet 1 thread"]
    assert any("setup.sh" in note for note in run.notes)


@pytest.mark.parametrize("turn_frames", [1, 2])
def test_thread_counts_are_timed_in_turns(model, monkeypatch, turn_frames):
    # A slow spell of a shared machine must hit every thread count alike.
    calls = []
    original = Detector.__call__

    def detect(self, frame):
        calls.append((self.threads, int(frame[0, 0, 0])))
        return original(self, frame)

    monkeypatch.setattr(Detector, "__call__", detect)
    frames = [np.full((180, 320, 3), k, np.uint8) for k in range(3)]
    run = run_benchmark(frames, threads=(2, 1), repeat=2, reference_frames=0, opencv=False,
                        model=model, log=lambda line: None, turn_frames=turn_frames)
    assert [r.name for r in run.results] == ["fastdet 1 thread", "fastdet 2 threads"]
    assert [len(r.seconds) for r in run.results] == [3, 3]
    # One untimed call each on the first frame, then per turn and thread count (1, then 2):
    # one untimed call on the turn's first frame, two timed calls on each of its frames.
    expected = [(1, 0), (2, 0)]
    for first in range(0, 3, turn_frames):
        for threads in (1, 2):
            expected += [(threads, first)]
            expected += [(threads, k) for k in range(first, min(first + turn_frames, 3))
                         for _ in range(2)]
    assert calls == expected


def test_floor_counts_votes_and_multiply_adds(model):
    plans = plan_scales(DetectorConfig(), model.options, (1280, 720))
    estimate = floor_estimate(plans, model, fastdet_ms=30.0)
    pixels = sum(p.scaled_size[0] * p.scaled_size[1] for p in plans)
    assert estimate["votes"] == pixels * 3
    assert estimate["macs"] == sum(p.n_windows for p in plans) * FeatureLayout(
        model.options).length
    assert estimate["distance"] == pytest.approx(30.0 / estimate["floor_ms"])


def test_the_floor_line_tells_2_4x_from_2_6x():
    # Rounded to whole times, both read "3x": the start-up issue's line is 2.5x.
    estimate = {"scaled_pixels": 1e6, "channels": 3, "votes": 3e6, "clock_hz": 3e9,
                "nominal_hz": None, "vote_ms": 1.0, "windows": 800, "feature_length": 8460,
                "macs": 6.8e6, "mac_rate": 5e10, "mac_ms": 0.14, "floor_ms": 1.0}
    for fastdet_ms, shown in ((2.44, "2.4x"), (2.56, "2.6x")):
        line = format_floor(dict(estimate, fastdet_ms=fastdet_ms,
                                 distance=fastdet_ms)).splitlines()[-1]
        assert line == f"- fastdet 1 thread: {fastdet_ms:.2f} ms = {shown} the floor"


def test_scaling_table_and_plot(tmp_path):
    points = [ScalingPoint("size", (640, 360), 5, t, 10.0 * t, 200, 250_000) for t in (1, 2)]
    points += [ScalingPoint("size", (1280, 720), 5, t, 30.0 * t, 861, 880_000) for t in (1, 2)]
    points += [ScalingPoint("scales", (1280, 720), n, 1, 6.0 * n, 170 * n, 170_000 * n)
               for n in range(1, 6)]
    table = format_scaling(points)
    assert "| 1280x720 | 0.92 | 0.88 | 861 | 30.0 | 60.0 | 0.0 |" in table
    assert "| first 5 |" in table
    png = plot_scaling(points, tmp_path / "scaling.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bench_command_prints_the_tables(capsys, model_path, data_dir):
    code = main(["bench", "--model", str(model_path), "--frames", "2", "--repeat", "1",
                 "--size", "640x360", "--threads", "1", "--reference-frames", "1",
                 "--no-opencv"])
    assert code == 0
    out = capsys.readouterr().out
    assert "| fastdet 1 thread | 2 |" in out
    assert "| reference | 1 |" in out
    assert "x faster than reference" in out
    assert "| stage (ms/frame) | resize+convert |" in out
    assert "| 640x360 |" in out  # fastdet.hog vs skimage line
    assert "floor:" in out


def test_bench_rejects_a_bad_size(capsys, model_path):
    assert main(["bench", "--model", str(model_path), "--size", "big"]) == EXIT_ERROR
    assert "--size must look like 1280x720" in capsys.readouterr().err


@pytest.mark.parametrize("option", ["--turn-frames", "--repeat"])
def test_bench_rejects_counts_below_one(capsys, model_path, option):
    assert main(["bench", "--model", str(model_path), option, "0"]) == EXIT_ERROR
    assert f"{option} must be at least 1, got 0" in capsys.readouterr().err


def test_bench_help_names_the_turn_frames_default(capsys):
    from fastdet.bench.timing import TURN_FRAMES
    with pytest.raises(SystemExit):
        main(["bench", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert f"untimed call (default {TURN_FRAMES})" in help_text


@pytest.mark.parametrize("threads", [["0"], ["1", "100000"]])
def test_bench_refuses_thread_counts_before_reading_frames(capsys, model_path, monkeypatch,
                                                           threads):
    """0 was refused only after decoding the video; 100000 started threads until
    "can't start new thread", an internal error (exit 70)."""
    import fastdet.bench.timing as timing

    monkeypatch.setattr(timing, "read_frames", lambda *a, **k: pytest.fail("frames were read"))
    assert main(["bench", "--model", str(model_path), "--threads", *threads]) == EXIT_ERROR
    assert f"--threads must be 1-256, got {threads[-1]}" in capsys.readouterr().err


@pytest.mark.parametrize("size", ["7x5", "100000x100000", "16384x16384"])
def test_bench_refuses_sizes_it_cannot_time(capsys, model_path, size):
    """7x5 ended in scikit-image's ValueError, 100000x100000 in OpenCV's failed 30 GB
    allocation, 16384x16384 in the labelling kernel: internal errors (exit 70)."""
    assert main(["bench", "--model", str(model_path), "--size", size]) == EXIT_ERROR
    assert f"--size sides must be 16-8192 pixels, got '{size}'" in capsys.readouterr().err


def test_bench_refuses_frames_that_would_not_fit_in_memory(capsys, model_path, monkeypatch):
    import fastdet.bench.timing as timing

    monkeypatch.setattr(timing, "read_frames", lambda *a, **k: pytest.fail("frames were read"))
    assert main(["bench", "--model", str(model_path), "--size", "8192x8192",
                 "--frames", "100000"]) == EXIT_ERROR
    err = capsys.readouterr().err
    assert err.startswith("fastdet: error: --size 8192x8192: 100000 frames would take 18750.0 GiB")
    assert err.count("\n") == 1


def test_bench_refuses_frames_smaller_than_every_window(capsys, model_path, data_dir):
    """No window to score: the physical floor divided by zero (an internal error)."""
    assert main(["bench", "--model", str(model_path), "--size", "16x16", "--frames", "1",
                 "--threads", "1", "--reference-frames", "0", "--no-opencv"]) == EXIT_ERROR
    err = capsys.readouterr().err
    assert "test_video.mp4 at 16x16 is smaller than every search window" in err


@pytest.mark.parametrize("options, message", [
    (["--video", "--frames", "5"], "--frames does not apply to --video"),
    (["--video", "--threads", "1", "2"], "--video takes one --threads count, got 2"),
    (["--long-run", "--threads", "1", "2"], "--long-run takes one --threads count, got 2"),
])
def test_bench_refuses_what_video_and_long_run_would_ignore(capsys, monkeypatch, options,
                                                            message):
    """Both time one `fastdet run` setting: --frames with --video and every thread
    count but the first were silently dropped."""
    import fastdet.cli.bench as bench

    monkeypatch.setattr(bench, "_video_benchmark", lambda *a: pytest.fail("benchmark ran"))
    monkeypatch.setattr(bench, "_long_run", lambda *a: pytest.fail("benchmark ran"))
    assert main(["bench", *options]) == EXIT_ERROR
    assert message in capsys.readouterr().err
