"""The kernel warm-up: it compiles what a detection needs, and can use a second process."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from fastdet.cli.app import EXIT_ERROR, main
from fastdet.kernels import warmup

_AFTER_WARMUP = r"""
import glob, json, sys
import cv2
import fastdet
from fastdet.kernels import warmup
from numba.core.registry import CPUDispatcher
import fastdet.kernels.colour, fastdet.kernels.convert, fastdet.kernels.heat, fastdet.kernels.hog
import fastdet.kernels.label, fastdet.kernels.resize, fastdet.kernels.score

def signatures():
    found = set()
    for name, module in sys.modules.items():
        if name.startswith("fastdet.kernels."):
            for attribute, value in vars(module).items():
                if isinstance(value, CPUDispatcher):
                    found |= {(name, attribute, str(sig)) for sig in value.signatures}
    return found

warmup.warm(warmup.DETECTION_FAMILIES, processes=1)
before = signatures()
detector = fastdet.Detector(threads=int(sys.argv[2]), preload=False)
frames = [cv2.imread(path) for path in sorted(glob.glob(sys.argv[1] + "/*.jpg"))]
for frame in frames:
    detector(frame)
print(json.dumps({"new": sorted(map(list, signatures() - before)), "before": len(before)}))
"""


@pytest.mark.parametrize("threads", [1, 2])
def test_detection_needs_nothing_the_warmup_did_not_load(data_dir, threads):
    """In a fresh process: after the warm-up, detecting loads and compiles no other kernel."""
    completed = subprocess.run(
        [sys.executable, "-c", _AFTER_WARMUP, str(data_dir / "test_images"), str(threads)],
        capture_output=True, text=True, timeout=900)
    assert completed.returncode == 0, completed.stderr[-3000:]
    result = json.loads(completed.stdout.strip().splitlines()[-1])
    assert result["before"] >= len(warmup.DETECTION_FAMILIES)
    assert result["new"] == [], result["new"]


def test_unknown_family_is_refused():
    with pytest.raises(ValueError, match="unknown kernel families"):
        warmup.warm(["nonsense"])


def test_cold_families_compiled_by_two_processes(tmp_path):
    """With an empty cache, ``fastdet warmup`` shares the families with a helper
    process, each compiled once; a second run finds them all in the cache."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    command = [sys.executable, "-c", "import sys; from fastdet.cli import console_main; "
               "console_main(sys.argv[1:])", "warmup", "--families", "resize", "heat",
               "--processes", "2"]
    first = subprocess.run(command, capture_output=True, text=True, env=env, timeout=900)
    assert first.returncode == 0, first.stderr[-3000:]
    for name in ("resize", "heat"):
        rows = [line for line in first.stdout.splitlines() if line.startswith(f"| {name} |")]
        assert len(rows) == 1 and rows[0].split("|")[2].strip() in (
            "compiled", "compiled (helper process)"), first.stdout
    second = subprocess.run(command, capture_output=True, text=True, env=env, timeout=900)
    assert second.returncode == 0, second.stderr[-3000:]
    assert second.stdout.count("loaded from the cache") == 2, second.stdout


class _FakeHelper:
    """A helper process that claimed ``taken`` before this one asked, and reports them."""

    def __init__(self, taken):
        self.taken, self.returncode = taken, 0

    def communicate(self):
        return json.dumps({name: 1.5 for name in self.taken}).encode(), b""


def test_two_processes_take_turns_in_the_heaviest_first_order(monkeypatch):
    calls = []
    monkeypatch.setattr(warmup, "FAMILIES", {name: (lambda name=name: calls.append(name))
                                             for name in ("label", "score", "heat", "convert")})
    monkeypatch.setattr(warmup, "cold_families", lambda names: list(names))
    monkeypatch.setattr(warmup, "take_early", lambda names: None)
    started = {}

    def start_helper(names, claims):
        started.update(names=list(names), folder=claims.folder)
        # The helper got to the heaviest and to heat first.
        assert claims.claim("label") and claims.claim("heat")
        return _FakeHelper(["label", "heat"])

    monkeypatch.setattr(warmup, "start_helper", start_helper)
    seconds = warmup.warm(["convert", "heat", "label", "score"], processes=2)
    assert started["names"] == ["label", "score", "heat", "convert"]
    # This process compiled what the helper had not claimed, in the same order,
    # then loaded the helper's families (from the cache) once it had finished.
    assert calls == ["score", "convert", "label", "heat"]
    assert seconds["helper"] == {"label": 1.5, "heat": 1.5}
    assert sorted(name for name in seconds if name != "helper") == sorted(calls)
    assert not os.path.exists(started["folder"])


def test_the_helper_compiles_only_what_it_claims(tmp_path):
    claims = warmup.FamilyClaims()
    try:
        assert claims.claim("heat")  # this process's
        env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
        done = subprocess.run([sys.executable, "-m", "fastdet.kernels.warmup", "--claims",
                               claims.folder, "heat", "convert"],
                              capture_output=True, text=True, env=env, timeout=900)
    finally:
        claims.remove()
    assert done.returncode == 0, done.stderr[-3000:]
    assert sorted(json.loads(done.stdout.strip().splitlines()[-1])) == ["convert"]


_HELPER_FROM_A_SHADOWED_FOLDER = r"""
import json, sys
sys.path = [p for p in sys.path if p not in ("", ".")]
from fastdet.compile_ahead import FamilyClaims, start_helper
claims = FamilyClaims()
helper = start_helper(["resize"], claims)
out, _ = helper.communicate(timeout=900)
claims.remove()
from fastdet.kernels.warmup import compiled_here, warm
warm(["resize"], processes=1)
print(json.dumps({"code": helper.returncode, "report": json.loads(out.decode().splitlines()[-1]),
                  "compiled_here": compiled_here("resize")}))
"""


def test_the_helper_process_compiles_this_fastdet_not_the_working_directorys(tmp_path):
    """Run from a folder holding another ``fastdet`` (a checkout beside an installed
    fastdet), the helper still compiles this one's kernels, into the folders this
    process loads them from."""
    shadow = tmp_path / "fastdet"
    shadow.mkdir()
    (shadow / "__init__.py").write_text("raise ImportError('the working directory's fastdet')\n")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    # This process imports the installed fastdet, as the console script does.
    completed = subprocess.run([sys.executable, "-c", _HELPER_FROM_A_SHADOWED_FOLDER],
                               capture_output=True, text=True, env=env, cwd=tmp_path,
                               timeout=900)
    assert completed.returncode == 0, completed.stderr[-3000:]
    result = json.loads(completed.stdout.strip().splitlines()[-1])
    assert result["code"] == 0 and list(result["report"]) == ["resize"], result
    assert result["compiled_here"] is False   # loaded from what the helper compiled


def test_warmup_command_reports_every_family(capsys):
    assert main(["warmup", "--families", "heat", "label", "--processes", "1"]) == 0
    out = capsys.readouterr().out
    assert "| heat |" in out and "| label |" in out and "2 families ready" in out


def test_warmup_rejects_bad_processes(capsys):
    assert main(["warmup", "--processes", "0"]) == EXIT_ERROR
    assert capsys.readouterr().err.startswith("fastdet: error: --processes")


def test_detector_waits_for_its_preload():
    import fastdet

    detector = fastdet.Detector(threads=1)
    frame = np.zeros((720, 1280, 3), np.uint8)
    assert len(detector(frame)) == 0
    assert detector._loader is None  # joined by the first detection


_TYPED_CALLEES = r"""
import json
from fastdet.kernels import colour, convert, hog, score, warmup

warmup.warm(["hog", "score", "colour", "convert"], processes=1)
typed = {}
for kernel in (hog._cell_rows_u8_fast, score._score_window_rows, colour._colour_maps,
               convert._bgr_to_hls):
    [signature] = kernel.signatures
    typemap = kernel.overloads[signature].type_annotation.typemap
    typed[kernel.__name__] = sorted({str(t) for t in typemap.values()
                                     if "intrinsic" in str(t) or "Dispatcher" in str(t)})
print(json.dumps({"typed": typed, "vector_tiles": colour.NATIVE_TILE_PATH != colour.PATH_SCALAR}))
"""


def test_a_detection_compiles_only_the_variants_it_runs(tmp_path):
    """In a fresh process with an empty cache: the detection's cell kernel types
    only the three-channel blocks, its scorer only the L2-Hys normaliser, and
    its colour maps no per-pixel lookup loop where the CPU has a vector path
    (each a branch Numba drops before typing; see the kernels' docstrings);
    the per-pixel tails of the cells and the colour conversion are kernels of
    their own (family "tails"), which the warm-up's shapes do not need."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    completed = subprocess.run([sys.executable, "-c", _TYPED_CALLEES], capture_output=True,
                               text=True, env=env, timeout=900)
    assert completed.returncode == 0, completed.stderr[-3000:]
    result = json.loads(completed.stdout.strip().splitlines()[-1])
    cells = " ".join(result["typed"]["_cell_rows_u8_fast"])
    assert "_group_block_c3_" in cells and "_group_block_c1" not in cells, cells
    assert "_scalar_cells" not in cells, cells
    assert "_hls_block" in " ".join(result["typed"]["_bgr_to_hls"])
    assert "_hls_scalar" not in " ".join(result["typed"]["_bgr_to_hls"])
    normalisers = [t for t in result["typed"]["_score_window_rows"] if "_normalise_blocks" in t]
    # L2-Hys one vector of positions at a time, and side by side; no other norm.
    assert normalisers == ["Function(<intrinsic _normalise_blocks_3>)",
                           "Function(<intrinsic _normalise_blocks_3x2>)"], normalisers
    colour = " ".join(result["typed"]["_colour_maps"])
    lookups = "_scalar_tile_row" in colour
    assert lookups != result["vector_tiles"], colour


def test_the_tails_family_compiles_the_per_pixel_tails():
    """``fastdet warmup`` (every family) leaves nothing for a frame width whose
    band or scales end in part of a vector block (1366 pixels, say): in a fresh
    process, the family alone loads or compiles both tail kernels."""
    code = ("from fastdet.kernels import convert, hog, warmup; "
            "warmup.warm(['tails'], processes=1); "
            "print(len(convert._hls_pixels.signatures), len(hog._cell_rows_u8_tail.signatures))")
    completed = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                               timeout=900)
    assert completed.returncode == 0, completed.stderr[-3000:]
    assert completed.stdout.split() == ["1", "1"], completed.stdout


def test_without_a_second_process_this_one_compiles_everything(monkeypatch):
    calls = []
    monkeypatch.setattr(warmup, "FAMILIES", {name: (lambda name=name: calls.append(name))
                                             for name in ("label", "heat")})
    monkeypatch.setattr(warmup, "cold_families", lambda names: list(names))
    monkeypatch.setattr(warmup, "take_early", lambda names: None)

    def no_process(names, claims):
        raise OSError("no processes left")

    monkeypatch.setattr(warmup, "start_helper", no_process)
    seconds = warmup.warm(["heat", "label"], processes=2)
    assert calls == ["label", "heat"] and "helper" not in seconds

    def no_folder():
        raise OSError("read-only /tmp")

    calls.clear()
    monkeypatch.setattr(warmup, "FamilyClaims", no_folder)
    seconds = warmup.warm(["heat", "label"], processes=2)
    assert calls == ["label", "heat"] and "helper" not in seconds


def test_a_family_named_twice_is_warmed_once(monkeypatch):
    """``warm(["heat", "heat"])`` counted two cold families and started a helper
    process for the one family; now it is one family, compiled here."""
    calls, helpers = [], []
    monkeypatch.setattr(warmup, "FAMILIES", {"heat": lambda: calls.append("heat")})
    monkeypatch.setattr(warmup, "cold_families", lambda names: list(names))
    monkeypatch.setattr(warmup, "take_early", lambda names: None)

    def no_process(names, claims):
        helpers.append(names)
        raise OSError("no processes left")

    monkeypatch.setattr(warmup, "start_helper", no_process)
    seconds = warmup.warm(["heat", "heat"], processes=2)
    assert calls == ["heat"] and helpers == [] and list(seconds) == ["heat"]


def test_warmup_command_lists_a_family_named_twice_once(capsys):
    assert main(["warmup", "--families", "heat", "heat", "--processes", "1"]) == 0
    out = capsys.readouterr().out
    assert out.count("| heat |") == 1 and "1 families ready" in out


def test_warmup_says_its_kernels_are_not_kept_in_an_unwritable_cache(tmp_path):
    """``fastdet warmup`` (building an image) with a cache folder it cannot write
    printed only the temporary folder's name, as if the kernels were kept."""
    blocked = tmp_path / "a-file"
    blocked.write_text("not a folder")
    environment = dict(os.environ, FASTDET_CACHE_DIR=str(blocked))
    environment.pop("NUMBA_CACHE_DIR", None)
    result = subprocess.run(
        [sys.executable, "-m", "fastdet.cli", "warmup", "--families", "convert", "--processes",
         "1"], capture_output=True, text=True, env=environment, timeout=300,
        cwd=os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
    assert result.returncode == 0, result.stderr
    assert "is not writable" in result.stdout and "kept for this run only" in result.stdout, \
        result.stdout
