"""Compile (or load from the cache) each kernel family once, on tiny inputs.

Numba compiles a kernel at its first call, for the types of that call.  Each
function of :data:`FAMILIES` calls one family's kernels the way the detector
calls them (the same dtypes, dimensions, layouts and argument kinds) on
inputs a few pixels wide, so that afterwards a detection finds every kernel
it needs compiled (a test holds the detector to that).  With a filled cache
that is a load from disk; with an empty one it is the compile, which
:func:`warm` can share with a second process (:func:`cold_families`).

Used by ``fastdet warmup`` (compile everything once, e.g. while building a
Docker image or starting a cluster worker) and by
:class:`fastdet.detector.detector.Detector`, which loads its families in a
background thread as soon as it is created.

``python -m fastdet.kernels.warmup [--claims FOLDER] FAMILY...`` compiles
the named families (with ``--claims``, those it claims first; see
:class:`fastdet.compile_ahead.FamilyClaims`) and prints one JSON line of
seconds per family it compiled or loaded.
"""

from __future__ import annotations

import json
import logging
import os
import sys
import time

import numpy as np

from ..compile_ahead import (DETECTION_FAMILIES, FamilyClaims, compile_order, start_helper,
                             stop_helper, take_early)

log = logging.getLogger("fastdet.kernels")


def _frame_band(height, width):
    """A BGR frame's full-width band, as the detector slices it."""
    frame = np.random.default_rng(0).integers(0, 256, (height + 4, width, 3), dtype=np.uint8)
    return frame[2:2 + height, 0:width]


def _warm_convert():
    from .convert import bgr_to_hls
    bgr_to_hls(_frame_band(4, 16))


def _warm_resize():
    from .resize import resize_linear
    converted = np.ascontiguousarray(_frame_band(12, 40))
    # A column-sliced region (strided rows) resized up, and a full-width one
    # halved exactly: the two kernels the default search runs.
    region = converted[1:11, 4:36]
    resize_linear(region, (48, 15), out=np.empty((15, 48, 3), np.uint8))
    resize_linear(converted[0:12], (20, 6), out=np.empty((6, 20, 3), np.uint8))


def _warm_hog():
    from .hog import cell_histograms, phase_layout_shape
    from .score import phase_scoring_pad
    image = np.ascontiguousarray(_frame_band(24, 48))
    pad = phase_scoring_pad(6, 2, (2, 2))
    out = np.empty(phase_layout_shape(3, 6, 3, 9, 2, pad), np.float32)
    cell_histograms(image, (8, 8), 9, out=out, phase_step=2, phase_pad=pad)


def _warm_score():
    from .score import phase_scoring_pad, score_window_rows
    pad = phase_scoring_pad(16, 2, (2, 2))
    cells = np.zeros((16, 3, 9, 2 * 8 + pad), np.float32)
    scores = np.zeros((5, 5), np.float32)
    # The detector's sizes: 64-pixel windows stepped by 16 pixels (2 cells),
    # spatial boxes of 2 pixels, histogram tiles of 16.
    score_window_rows(scores, (0, 5), 64, 16,
                      hog=(cells, 16, (2, 2), "L2-Hys", np.zeros((7, 7, 108), np.float32), 2),
                      spatial=(np.zeros((72, 72, 3), np.float32), np.zeros((32, 32, 3), np.float32)),
                      tiles=(np.zeros((9, 9), np.float32), 16))


def band_scale_calls():
    """A small scale's bound calls and their arguments, as the detector binds them
    (:class:`fastdet.detector.scoring._ScaleWork`): ``(cell_rows, colour_rows,
    windows, (cells_args, colour_args, windows_args))``.

    64-pixel windows stepped by 16 pixels (2 cells), spatial boxes of 2
    pixels, histogram tiles of 16; 12 cell columns, whole groups of cells.
    """
    from .colour import ColourMapRows
    from .hog import PhaseCellRows, phase_layout_shape
    from .score import WindowRowScorer, phase_scoring_pad
    image = np.ascontiguousarray(_frame_band(72, 96))
    pad = phase_scoring_pad(12, 2, (2, 2))
    cells = np.zeros(phase_layout_shape(9, 12, 3, 9, 2, pad), np.float32)
    cell_rows = PhaseCellRows(image.shape, (8, 8), 9, cells, 2, pad)
    lut = np.ascontiguousarray(np.repeat(np.ones((3, 32), np.float32), 8, axis=1))
    tiles, box = np.empty((4, 6), np.float32), np.empty((32, 48, 3), np.float32)
    colour_rows = ColourMapRows((64, 96, 3), lut, 16, 2, (tiles, box))
    windows = WindowRowScorer((1, 3), 64, 16,
                              (cells, 12, (2, 2), "L2-Hys", np.zeros((7, 7, 108), np.float32), 2),
                              (box, np.zeros((32, 32, 3), np.float32)), (tiles, 16))
    arguments = (cell_rows.call(image, 0, 8)[1], colour_rows.arguments(image[:64], 0, 64),
                 windows.arguments(np.zeros((1, 3), np.float32), 0, 1))
    return cell_rows, colour_rows, windows, arguments


def _warm_band():
    from .band import BandScorer
    cell_rows, colour_rows, windows, arguments = band_scale_calls()
    if BandScorer.fits(cell_rows, colour_rows, windows):
        # The band kernel alone: the kernels it calls are families of their
        # own, which the other compiling process may be compiling now.
        BandScorer.compile_band_kernel(*arguments)


def _warm_colour():
    from .colour import colour_maps
    image = np.ascontiguousarray(_frame_band(16, 32))
    lut = np.ascontiguousarray(np.repeat(np.ones((3, 32), np.float32), 8, axis=1))
    colour_maps(image, lut, 8, 2)


def _warm_heat():
    from .heat import box_heat_region, windows_above
    boxes = np.array([[2, 2, 10, 10], [6, 4, 14, 12]], np.int32)
    windows_above(np.ones(2, np.float32), np.float32(0.5), boxes, np.zeros(2, np.int64))
    box_heat_region(boxes, np.ones(2, np.float32), 32, 16)


def _two_blob_heat():
    heat = np.zeros((24, 40), np.float32)
    heat[4:20, 2:16] = 2.0
    heat[4:20, 20:34] = 2.0
    heat[10:14, 16:20] = 1.5
    return heat


def _warm_label():
    from .label import heat_blobs
    heat_blobs(_two_blob_heat(), 0, 0, 1.0, True, True, np.float32(0.3), 8, 4,
               np.linspace(0.2, 0.8, 5))


def _warm_refine():
    from .refine import box_heat_features, refined_edges, snap_box_sides
    boxes = np.array([[2, 4, 16, 20]], np.int64)
    features = np.empty((1, 11))
    box_heat_features(_two_blob_heat(), 0, 0, boxes, 1.0, 40, 24, np.array([0.5]), features)
    refined_edges(boxes, features, np.zeros((4, 11)), np.array([40.0]), np.empty((1, 4)))
    snap_box_sides(np.ascontiguousarray(_frame_band(24, 40)), boxes, 0.1,
                   np.array([0, 0, 40, 24], np.int64), np.empty((1, 4), np.int64))


def _warm_split():
    from .label import component_boxes, label_components, split_component, split_levels
    heat = _two_blob_heat()
    levels = np.linspace(0.2, 0.8, 5)
    labels, count = label_components(heat > 1.0, 8)
    component_boxes(labels, count)
    split = split_levels(np.float32(2.0), 1.0, levels)
    mask = np.ascontiguousarray(labels == 1).view(np.uint8)
    split_component(np.ascontiguousarray(heat), mask, split, 4, 4, 8)


def _warm_smooth():
    from .heat import decay_heat
    decay_heat(np.zeros((6, 8), np.float32), np.ones((2, 3), np.float32), 1, 2,
               np.float32(0.75), np.float32(0.25))


def _warm_track():
    from .patch import (grey_thumbnail, mask_overlap_search, saturation_mask,
                        sum_squared_difference)
    patch = np.ascontiguousarray(_frame_band(16, 16))
    mask = saturation_mask(patch, 100)
    mask_overlap_search(mask, mask, (8, 8), 2, 1)
    thumb = grey_thumbnail(patch, 4)
    sum_squared_difference(thumb, thumb)


def _warm_tails():
    from .convert import bgr_to_hls
    from .hog import cell_histograms, phase_layout_shape
    from .score import phase_scoring_pad
    # A band of a 16-pixel block and 4 pixels more, and an image of 7 cell
    # columns: the per-pixel kernels after the vector ones' whole blocks.
    bgr_to_hls(_frame_band(4, 20))
    image = np.ascontiguousarray(_frame_band(24, 56))
    pad = phase_scoring_pad(7, 2, (2, 2))
    out = np.empty(phase_layout_shape(3, 7, 3, 9, 2, pad), np.float32)
    cell_histograms(image, (8, 8), 9, out=out, phase_step=2, phase_pad=pad)


def _warm_hog_api():
    from .blocks import normalize_blocks
    from .hog import cell_histograms
    grey = np.ascontiguousarray(_frame_band(24, 24)[:, :, :1])
    normalize_blocks(cell_histograms(grey, (8, 8), 9), (2, 2), "L2-Hys")


#: Each family's warm-up, by name.  "label" is what every detection runs
#: (heat_blobs); "refine" the box refinement of the default config (a family
#: of its own, so that a cold compile can put it in the other process than
#: "label", the heaviest); "split" the full-resolution split of a blob
#: holding two cars; "smooth" the video pipeline's heat smoothing (every
#: default run) and "track" its patch tracking (``--track`` only: 3.5 s of
#: compile against 0.45 s, so the two are apart); "tails" the per-pixel
#: kernels for the pixels past the colour conversion's whole vector blocks
#: and the cells past the cell kernel's whole groups (frame widths such as
#: 1366, not the default search at 640-1920 pixels of 16:9 frames); "band" a
#: scale's cells, colour maps and scores in one call (:mod:`.band`), which
#: compiles the kernels of "hog", "score" and "colour" that it calls, so a
#: detection with the default options needs it instead of those three.
FAMILIES = {"convert": _warm_convert, "resize": _warm_resize, "hog": _warm_hog,
            "score": _warm_score, "colour": _warm_colour, "band": _warm_band, "heat": _warm_heat,
            "label": _warm_label, "refine": _warm_refine, "split": _warm_split,
            "smooth": _warm_smooth, "track": _warm_track, "hog_api": _warm_hog_api,
            "tails": _warm_tails}

#: One dispatcher per family whose cache entry tells whether the family was
#: compiled before (see :func:`cold_families`): module, name.
_PROBES = {"convert": ("convert", "_bgr_to_hls"), "resize": ("resize", "_resize"),
           "hog": ("hog", "_cell_rows_u8_fast"), "score": ("score", "_score_window_rows"),
           "colour": ("colour", "_colour_maps"), "band": ("band", "_features_and_scores"),
           "heat": ("heat", "box_heat_region"),
           "label": ("label", "heat_blobs"), "refine": ("refine", "box_heat_features"),
           "split": ("label", "split_component"),
           "smooth": ("heat", "decay_heat"),
           "track": ("patch", "mask_overlap_search"),
           "hog_api": ("blocks", "_normalize_serial"),
           "tails": ("convert", "_hls_pixels")}


def _probe(name):
    import importlib

    module_name, attribute = _PROBES[name]
    return getattr(importlib.import_module(f"{__package__}.{module_name}"), attribute, None)


def compiled_here(name):
    """Whether this process compiled family ``name``'s main kernel (rather than loading it)."""
    stats = getattr(_probe(name), "stats", None)
    return bool(stats is not None and stats.cache_misses and not stats.cache_hits)


def cold_families(names):
    """The families among ``names`` that have nothing in the kernel cache yet.

    A family counts as cold when its main kernel has neither a compiled
    version in this process nor an index file in the cache folder (Numba
    writes one per cached function).  Stale entries (edited sources) count
    as warm: Numba recompiles those itself.
    """
    cold = []
    for name in names:
        dispatcher = _probe(name)
        if dispatcher is None or dispatcher.signatures:
            continue
        index = getattr(getattr(getattr(dispatcher, "_cache", None), "_cache_file", None),
                        "_index_path", None)
        if index is not None and not os.path.exists(index):
            cold.append(name)
    return cold


def warm(names=DETECTION_FAMILIES, processes=None, claims=None):
    """Compile or load the kernel families ``names``; returns seconds per family.

    Parameters
    ----------
    names : sequence of str
        Keys of :data:`FAMILIES`; one given twice is warmed once.
    processes : int, optional
        With 2 or more and families still uncompiled (:func:`cold_families`),
        a second Python process shares the compile: both take the families
        heaviest first (:func:`fastdet.compile_ahead.compile_order`), each
        compiling the next one the other has not claimed, and this one then
        loads the helper's from the cache.  The ``fastdet`` command may have
        started that process already, before its imports
        (:func:`fastdet.compile_ahead.start_early`).  ``None``: 2 when there
        are two or more CPU cores.
    claims : FamilyClaims, optional
        The helper's side: only the families claimed here first are
        compiled, the others skipped (``processes`` is then ignored).

    Returns
    -------
    dict
        ``{family: seconds}`` in this process (a family compiled by the
        helper process shows its load time here; see ``helper``), and
        ``"helper"``: ``{family: seconds}`` the helper process reported.
    """
    unknown = [name for name in names if name not in FAMILIES]
    if unknown:
        raise ValueError(f"unknown kernel families {unknown}; known: {sorted(FAMILIES)}")
    # A family named twice (``fastdet warmup --families label label``) would
    # otherwise count as two cold families and start a helper process for one.
    names = list(dict.fromkeys(names))
    if claims is not None:
        return {name: _run(name) for name in compile_order(names) if claims.claim(name)}
    if processes is None:
        processes = 2 if (os.cpu_count() or 1) > 1 else 1
    helper, shared = None, []
    early = take_early(names) if processes > 1 else None
    if early is not None:
        helper, shared, claims = early
        log.info("compiling kernels in two processes, each taking the next family as it "
                 "finishes one (the second started before fastdet's imports)")
    elif processes > 1:
        shared = compile_order(cold_families(names))
        try:
            claims = FamilyClaims() if len(shared) > 1 else None
        except OSError:  # no temporary folder to be had: this process compiles alone
            claims = None
        if claims is not None:
            try:
                helper = start_helper(shared, claims)
            except OSError:  # no second process to be had: likewise
                claims.remove()
                claims = None
        if claims is None:
            shared = []
        else:
            log.info("compiling kernels in two processes, each taking the next family as it "
                     "finishes one")
    seconds, helpers = {}, []
    try:
        for name in compile_order(names):
            if name in shared and not claims.claim(name):
                helpers.append(name)
                continue
            seconds[name] = _run(name)
        helper_seconds = {}
        if helper is not None:
            output, _ = helper.communicate()
            helper_seconds = _parse_report(output) if helper.returncode == 0 else {}
    except BaseException:
        # Interrupted (Ctrl-C in `fastdet warmup`): the helper's compile is abandoned too.
        if helper is not None:
            stop_helper(helper, claims)
        raise
    finally:
        if claims is not None:
            claims.remove()
    # The helper's families, from the cache (compiled here if the helper failed).
    for name in helpers:
        seconds[name] = _run(name)
    if shared:
        seconds["helper"] = {name: helper_seconds[name] for name in helpers
                             if name in helper_seconds}
    return seconds


def _run(name):
    start = time.perf_counter()
    FAMILIES[name]()
    return time.perf_counter() - start


def _parse_report(output):
    try:
        return json.loads(output.decode().strip().splitlines()[-1])
    except (ValueError, IndexError):
        return {}


def main(argv=None):
    """``python -m fastdet.kernels.warmup [--claims FOLDER] FAMILY...``: compile, print
    seconds as JSON."""
    names = list(sys.argv[1:] if argv is None else argv)
    claims = None
    if names[:1] == ["--claims"]:
        claims = FamilyClaims(names[1])
        names = names[2:]
    print(json.dumps(warm(names or list(FAMILIES), processes=1, claims=claims)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
