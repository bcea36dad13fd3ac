"""Every vector path of the kernels, on every CPU target this machine can run.

The kernels choose their SIMD paths from the instruction sets of the CPU
Numba compiles for (:mod:`fastdet.kernels._llvm`), which ``NUMBA_CPU_NAME``
and ``NUMBA_CPU_FEATURES`` select.  Each target below is compiled in a
subprocess with its own empty ``NUMBA_CACHE_DIR``:

* ``native``: the host CPU (AVX-512 on the development machine);
* ``haswell``: ``NUMBA_CPU_NAME=haswell NUMBA_CPU_FEATURES=`` -- Haswell's own
  features, i.e. AVX2 and no AVX-512.  (``NUMBA_CPU_NAME=haswell`` alone is
  *not* an AVX2 target: Numba then adds the host's features, AVX-512
  included.)
* ``sandybridge``: AVX and SSSE3 but no AVX2 and no FMA (Intel's cores of
  2011-2013): the 4-lane cell blocks with AVX, and the fused multiply-adds
  emulated in float64 (:func:`fastdet.kernels._llvm.fused_multiply_add`);
* ``generic``: ``NUMBA_CPU_NAME=generic``: baseline x86-64 (SSE2), no FMA
  either.

Default profile (:func:`test_target_matches_native_and_naive`): the script at
the bottom of this file runs every kernel family on small inputs chosen to
reach each vector path (both channel counts and the first/last-group blocks
of the cells, every resize path the target has, the colour bin-table paths,
the HLS blocks, the phase scorer), checks each against its naive reference
or OpenCV, and saves the outputs; the test then requires every one of them
bit-identical to the native target's: the cells (16, 8 and 4 lanes), block
norms, HOG and spatial scores, colour tile sums (AVX-512, AVX2 and per-pixel
paths), resize, HLS, heat, labels and the whole detector's margins on a real
frame.  11-30 s per target, nearly all of it compiling; the targets compile
side by side, one per core (the module: 59 s against 94 s one after another on
the two cores of an AMD EPYC, Zen 3).

Full profile (``-m slow``, :func:`test_kernel_tests_pass_on_target`): the
whole kernel test suite under each target, several minutes per target.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

HERE = Path(__file__).resolve()
#: tests/, where naive.py lives.
TESTS = HERE.parents[1]

#: Environment of each CPU target (besides its own NUMBA_CACHE_DIR).
TARGETS = {
    "native": {},
    "haswell": {"NUMBA_CPU_NAME": "haswell", "NUMBA_CPU_FEATURES": ""},
    "sandybridge": {"NUMBA_CPU_NAME": "sandybridge", "NUMBA_CPU_FEATURES": ""},
    "generic": {"NUMBA_CPU_NAME": "generic", "NUMBA_CPU_FEATURES": ""},
}

# Every output is required bit-identical across targets.  The block norms and
# the spatial dot products are written with a fixed summation order and no
# fused products (blocks.py, score.py): with LLVM's reassociating vectoriser
# they rounded by the target's vector width (an AMD Zen 4 with AVX-512: up to
# 4.5e-8 in blocks and 9.8e-4 on spatial scores of magnitude ~1e3 against its
# AVX2 build).  The colour tile sums' per-pixel lookups (generic) add in the
# bin-table paths' order (colour.py).


def target_environment(name, cache_dir):
    environment = {key: value for key, value in os.environ.items()
                   if key not in ("NUMBA_CPU_NAME", "NUMBA_CPU_FEATURES")}
    environment.update(TARGETS[name])
    environment["NUMBA_CACHE_DIR"] = str(cache_dir)
    environment["PYTHONPATH"] = os.pathsep.join(
        [str(TESTS)] + [p for p in [environment.get("PYTHONPATH")] if p])
    return environment


def _run_target(name, folder):
    """``(paths, arrays)`` of the script compiled for target ``name``, or its output on failure."""
    out = folder / "outputs.npz"
    completed = subprocess.run(
        [sys.executable, str(HERE), str(out)], env=target_environment(name, folder / "numba"),
        capture_output=True, text=True, timeout=900)
    if completed.returncode != 0:
        return completed.stdout + completed.stderr
    paths = json.loads(completed.stdout.strip().splitlines()[-1])
    with np.load(out) as arrays:
        return paths, {key: arrays[key] for key in arrays.files}


@pytest.fixture(scope="module")
def fingerprints(tmp_path_factory):
    """Run the script for every target once; ``{target: (paths, arrays)}``.

    The targets compile side by side, one per core: each is a single-threaded
    compile of every kernel family (the module took 94 s one after another on
    the two cores of an AMD EPYC, Zen 3).
    """
    folders = {name: tmp_path_factory.mktemp(f"cpu_{name}") for name in TARGETS}
    with ThreadPoolExecutor(max_workers=max(1, min(len(TARGETS), os.cpu_count() or 1))) as pool:
        futures = {name: pool.submit(_run_target, name, folder) for name, folder in folders.items()}
        return {name: future.result() for name, future in futures.items()}


@pytest.mark.parametrize("target", list(TARGETS))
def test_target_matches_native_and_naive(fingerprints, target):
    result = fingerprints[target]
    assert not isinstance(result, str), f"{target} failed:\n{result}"
    paths, arrays = result
    native = fingerprints["native"]
    assert not isinstance(native, str), f"native failed:\n{native}"
    _, expected = native
    assert sorted(arrays) == sorted(expected)
    for key in arrays:
        np.testing.assert_array_equal(arrays[key], expected[key], err_msg=f"{target}: {key}")


def test_targets_take_their_own_paths(fingerprints):
    """The targets really exercise different vector paths on this machine."""
    paths = {name: result[0] for name, result in fingerprints.items()
             if not isinstance(result, str)}
    assert paths.get("haswell", {}).get("avx2") is True
    assert paths["haswell"]["avx512f"] is False
    assert paths["haswell"]["hog_lanes"] == 8
    assert paths["haswell"]["colour_path"] == 2       # PATH_AVX2
    assert paths["haswell"]["fma"] is True
    assert paths.get("sandybridge", {}).get("ssse3") is True
    assert paths["sandybridge"]["avx2"] is False and paths["sandybridge"]["fma"] is False
    assert paths["sandybridge"]["hog_lanes"] == 4
    assert paths.get("generic", {}).get("ssse3") is False
    assert paths["generic"]["fma"] is False
    assert paths["generic"]["hog_lanes"] == 4
    assert paths["generic"]["colour_path"] == 1       # PATH_SCALAR


@pytest.mark.slow
@pytest.mark.parametrize("target", ["haswell", "sandybridge", "generic"])
def test_kernel_tests_pass_on_target(tmp_path, target):
    """The whole kernel test suite, compiled for ``target`` (several minutes)."""
    modules = sorted(str(p) for p in HERE.parent.glob("test_*.py") if p != HERE)
    completed = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *modules],
        env=target_environment(target, tmp_path / "numba"), cwd=TESTS.parent,
        capture_output=True, text=True, timeout=3600)
    assert completed.returncode == 0, completed.stdout[-5000:] + completed.stderr[-5000:]


# -- the script each target runs ------------------------------------------------

def _outputs():
    """Every kernel family on small inputs, checked against its reference.

    Returns ``(paths, arrays)``: the vector paths this target takes and the
    outputs to compare across targets.
    """
    import cv2

    from fastdet.kernels import _llvm, hog
    from fastdet.kernels.blocks import normalize_blocks
    import fastdet.kernels.colour as colour_kernels
    from fastdet.kernels.colour import colour_maps
    from fastdet.kernels.convert import bgr_to_hls
    from fastdet.kernels.heat import accumulate_heat
    from fastdet.kernels.label import component_boxes, label_components
    from fastdet.kernels.resize import resize_linear
    from fastdet.kernels.score import (add_hog_scores_from_phase_cells, add_spatial_scores,
                                       add_tile_window_sums, phase_scoring_pad,
                                       score_window_rows)
    from naive import (naive_cell_histograms, naive_component_boxes, naive_heat,
                       naive_normalize_blocks, naive_tile_weight_sums, naive_window_sums)

    rng = np.random.default_rng(15)
    arrays = {}
    # Cells: 3 and 1 channels; widths of one group (first and last block at
    # once), several groups and leftover cells (the scalar cells).
    for channels in (3, 1):
        for height, width in ((16, 16), (40, 48), (27, 61)):
            image = rng.integers(0, 256, (height, width, channels), dtype=np.uint8)
            image[3:9, 5:12] = 200  # flat patches: zero gradients, empty bins
            cells = hog.cell_histograms(image, (8, 8), 9)
            np.testing.assert_allclose(cells, naive_cell_histograms(image, (8, 8), 9),
                                       rtol=0, atol=2e-6 * max(1.0, float(cells.max())))
            arrays[f"cells_{channels}_{height}x{width}"] = cells
            arrays[f"phase_{channels}_{height}x{width}"] = hog.cell_histograms(
                image, (8, 8), 9, phase_step=2, phase_pad=3)
    # Blocks and the phase scorer.
    image = rng.integers(0, 256, (88, 136, 3), dtype=np.uint8)
    cells = hog.cell_histograms(image, (8, 8), 9)
    blocks = normalize_blocks(cells, (2, 2), "L2-Hys")
    np.testing.assert_allclose(blocks, naive_normalize_blocks(cells.astype(np.float64), (2, 2),
                                                              "L2-Hys"), rtol=1e-5, atol=2e-6)
    arrays["blocks"] = blocks
    weights = rng.normal(size=(7, 7, blocks.shape[2])).astype(np.float32)
    for step in (1, 2):
        grid = ((blocks.shape[0] - 7) // step + 1, (blocks.shape[1] - 7) // step + 1)
        scores = np.zeros(grid, np.float32)
        phase = hog.cell_histograms(image, (8, 8), 9, phase_step=step,
                                    phase_pad=phase_scoring_pad(cells.shape[1], step, (2, 2)))
        add_hog_scores_from_phase_cells(phase, cells.shape[1], (2, 2), "L2-Hys", weights, step,
                                        scores)
        expected = naive_window_sums(blocks, weights, step, grid)
        np.testing.assert_allclose(scores, expected, rtol=1e-4, atol=1e-4)
        arrays[f"scores_step{step}"] = scores
    # Resize: every path the target has (bit-identical to OpenCV), and halving.
    source = rng.integers(0, 256, (75, 203, 3), dtype=np.uint8)
    for size in ((64, 32), (101, 37), (150, 61), (406, 150)):
        resized = resize_linear(source, size)
        np.testing.assert_array_equal(resized, cv2.resize(source, size,
                                                          interpolation=cv2.INTER_LINEAR))
        arrays[f"resize_{size[0]}x{size[1]}"] = resized
    even = np.ascontiguousarray(source[:74, :202])
    arrays["halve"] = resize_linear(even, (101, 37))
    np.testing.assert_array_equal(arrays["halve"], cv2.resize(even, (101, 37),
                                                              interpolation=cv2.INTER_LINEAR))
    grey = np.ascontiguousarray(source[:, :, :1])
    arrays["resize_grey"] = resize_linear(grey, (97, 41))
    np.testing.assert_array_equal(arrays["resize_grey"][:, :, 0], cv2.resize(
        grey[:, :, 0], (97, 41), interpolation=cv2.INTER_LINEAR))
    # HLS: all 2**24 colours are tested elsewhere; here one image of width 8k.
    bgr = rng.integers(0, 256, (9, 80, 3), dtype=np.uint8)
    arrays["hls"] = bgr_to_hls(bgr)
    np.testing.assert_array_equal(arrays["hls"], cv2.cvtColor(bgr, cv2.COLOR_BGR2HLS))
    # Colour maps: a 32-bin lut (the bin-table path where there is one) and a
    # random one (scalar lookups everywhere).
    colour = rng.integers(0, 256, (48, 100, 3), dtype=np.uint8)
    binned = np.ascontiguousarray(rng.normal(size=(3, 32)).astype(np.float32)[
        :, np.arange(256) // 8])
    free = rng.normal(size=(3, 256)).astype(np.float32)
    for name, lut in (("binned", binned), ("free", free)):
        tiles, box = colour_maps(colour, lut, 8, 2)
        reference = naive_tile_weight_sums(colour, lut, 8)
        np.testing.assert_allclose(tiles, reference, rtol=1e-5, atol=1e-4)
        arrays[f"colour_tiles_{name}"] = tiles
        arrays[f"colour_box_{name}"] = box
    spatial_scores = np.zeros((3, 7), np.float32)
    add_spatial_scores(box, rng.normal(size=(16, 16, 3)).astype(np.float32), 4, spatial_scores)
    arrays["spatial_scores"] = spatial_scores
    tile_scores = np.zeros((3, 5), np.float32)
    add_tile_window_sums(tiles, 4, 1, tile_scores)
    arrays["tile_scores"] = tile_scores
    # The detector's one call for the three parts adds what the three kernels
    # add, on this target (windows of 64 pixels stepped by 16 on the 88x136
    # image of the phase scorer above).
    scale_tiles, scale_box = colour_maps(image, binned, 16, 2)
    spatial_weights = rng.normal(size=(32, 32, 3)).astype(np.float32)
    pad = phase_scoring_pad(cells.shape[1], 2, (2, 2))
    phase = hog.cell_histograms(image, (8, 8), 9, phase_step=2, phase_pad=pad)
    fused = np.zeros((2, 5), np.float32)
    score_window_rows(fused, (0, 2), 64, 16,
                      hog=(phase, cells.shape[1], (2, 2), "L2-Hys", weights, 2),
                      spatial=(scale_box, spatial_weights), tiles=(scale_tiles, 16))
    separate = np.zeros((2, 5), np.float32)
    add_hog_scores_from_phase_cells(phase, cells.shape[1], (2, 2), "L2-Hys", weights, 2,
                                    separate)
    add_spatial_scores(scale_box[:40], spatial_weights, 8, separate)
    add_tile_window_sums(scale_tiles, 4, 1, separate)
    np.testing.assert_array_equal(fused, separate)
    arrays["fused_scores"] = fused
    # Heat and labels.
    boxes = rng.integers(0, 60, (40, 4)).astype(np.int32)
    boxes[:, 2:] = boxes[:, :2] + rng.integers(4, 30, (40, 2))
    heat_weights = rng.random(40).astype(np.float32)
    heat = accumulate_heat(boxes, heat_weights, 80, 90)
    np.testing.assert_allclose(heat, naive_heat(boxes, heat_weights, 80, 90), rtol=1e-5,
                               atol=1e-5)
    arrays["heat"] = heat
    labels, count = label_components(heat > 1.0, 8)
    arrays["labels"] = labels
    np.testing.assert_array_equal(component_boxes(labels, count),
                                  naive_component_boxes(labels, count))
    # The whole detector, bundled model and default search, on a real frame:
    # every window's margin.
    from fastdet import Detector
    from fastdet.files.shared_data import data_dir

    frame = cv2.imread(str(data_dir() / "test_images" / "test1.jpg"))
    detector = Detector(threads=1, preload=False)
    prepared = detector.prepare(frame)
    arrays["detector_margins"] = np.concatenate([
        detector.score_scale(prepared, plan).ravel()
        for plan in detector.plans((frame.shape[1], frame.shape[0]))])
    paths = {"ssse3": _llvm.HAVE_SSSE3, "avx2": _llvm.HAVE_AVX2, "fma": _llvm.HAVE_FMA,
             "avx512f": _llvm.HAVE_AVX512F, "avx512bw": _llvm.HAVE_AVX512BW,
             "hog_lanes": hog._LANES, "colour_path": colour_kernels.TILE_PATH}
    return paths, arrays


if __name__ == "__main__":
    sys.path.insert(0, str(TESTS))
    found_paths, found = _outputs()
    np.savez(sys.argv[1], **found)
    print(json.dumps(found_paths))
