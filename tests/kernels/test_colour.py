"""``fastdet.kernels.colour.colour_maps`` against plain numpy.

The box mean must match ``float32(sum of bytes) * float32(1 / factor**2)``
bit for bit; the tile sums must match a float64 sum of the per-pixel weights to
float32 rounding, i.e. within 1e-5 of the tile's sum of absolute weights (one
wrong pixel in a tile is off by about 1 / (3 * tile**2) of it).

Shapes are chosen to hit every code path: whole 16-pixel box blocks plus
leftover pixels for factors 1, 2 and 4, the per-pixel box path (factor 3),
tile rows whose columns come four at a time and one at a time, images smaller
than a tile or a box cell, and tile rows and box rows that end at different
image rows.

Tile sums have three paths, each checked where the CPU has it (the ``path``
fixture): the bin-table paths (AVX-512BW, else AVX2), taken when each
channel's lut is constant on aligned runs of 8 values (the detector's lut for
32 bins or fewer), and the per-pixel table lookups for any lut.  Luts of both
kinds are used, and vector blocks (16 pixels with AVX-512, 32 with AVX2) with
tails of whole tiles after them (and, with AVX-512, the bottom tile row's last
block, which would read past the image).  Every path adds in one order,
checked bit for bit (``naive_bin_order_tile_sums``).
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import cv2
import numpy as np
import pytest

import fastdet.kernels.colour as colour_module
from fastdet.kernels.colour import PATH_AVX2, PATH_AVX512, PATH_SCALAR, _colour_maps, colour_maps
from naive import naive_bin_order_tile_sums

#: The tile-sum paths this machine's kernels have: every one is checked.
PATHS = {name: code for name, code, usable in (
    ("avx512", PATH_AVX512, colour_module.TILE_PATH == PATH_AVX512),
    ("avx2", PATH_AVX2, colour_module.TILE_PATH == PATH_AVX2),
    ("scalar", PATH_SCALAR, True)) if usable}


@pytest.fixture(params=list(PATHS))
def path(request, monkeypatch):
    """Run the test with one tile-sum path asked for; the path's kernel code."""
    monkeypatch.setattr(colour_module, "TILE_PATH", PATHS[request.param])
    return PATHS[request.param]


def reference_tiles(image, lut, tile):
    """float64 tile sums of sum_c lut[c, v_c] and of sum_c |lut[c, v_c]|."""
    lut = np.asarray(lut, np.float64)
    channels = [image[..., c] for c in range(3)]
    weight = sum(lut[c][channels[c]] for c in range(3))
    magnitude = sum(np.abs(lut[c])[channels[c]] for c in range(3))
    th, tw = image.shape[0] // tile, image.shape[1] // tile

    def sums(per_pixel):
        return per_pixel[:th * tile, :tw * tile].reshape(th, tile, tw, tile).sum(axis=(1, 3))

    return sums(weight), sums(magnitude)


def reference_box(image, factor):
    """float32(sum of each factor x factor cell) * float32(1 / factor**2)."""
    bh, bw = image.shape[0] // factor, image.shape[1] // factor
    cells = image[:bh * factor, :bw * factor].astype(np.int64)
    sums = cells.reshape(bh, factor, bw, factor, 3).sum(axis=(1, 3))
    return sums.astype(np.float32) * np.float32(1.0 / (factor * factor))


def check(image, lut, tile, factor):
    tiles, box = colour_maps(image, lut, tile, factor)
    assert tiles.dtype == np.float32 and box.dtype == np.float32
    if lut is None:
        assert tiles.shape == (0, 0)
    else:
        expected, magnitude = reference_tiles(image, lut, tile)
        assert tiles.shape == expected.shape
        np.testing.assert_array_less(np.abs(tiles - expected), 1e-5 * magnitude + 1e-30)
    if factor == 0:
        assert box.shape == (0, 0, 3)
    else:
        np.testing.assert_array_equal(box, reference_box(image, factor))
    return tiles, box


def random_lut(rng):
    return rng.normal(size=(3, 256)).astype(np.float32)


def binned_lut(rng, bins=32):
    """The detector's kind of lut: per-channel bin weights, ``bins`` equal bins."""
    bin_weights = rng.normal(size=(3, bins)).astype(np.float32)
    return np.ascontiguousarray(bin_weights[:, np.arange(256) * bins // 256])


#: Luts the bin-table path takes (bins dividing 32) and ones it must not.
BINNED = [32, 16, 8, 1]
NOT_BINNED = [64, 24, 256]
LUT_KINDS = [f"bins{b}" for b in BINNED + NOT_BINNED] + ["random"]


def make_lut(kind, rng):
    return random_lut(rng) if kind == "random" else binned_lut(rng, int(kind[4:]))


def tile_path(monkeypatch, image, lut, tile, factor, asked):
    """The tile-sum path colour_maps takes for ``lut`` when it asks for ``asked``."""
    taken = []
    kernel = colour_module._colour_maps
    with monkeypatch.context() as patch:
        patch.setattr(colour_module, "TILE_PATH", asked)
        patch.setattr(colour_module, "_colour_maps", lambda *args: taken.append(kernel(*args)))
        colour_maps(image, lut, tile, factor)
    return taken[0]


def kernel_maps(path, image, lut, tile, factor, tiles, box):
    """_colour_maps as ColourMapRows calls it: the vector path only for a lut with a bin table."""
    lut = np.ascontiguousarray(lut, np.float32)
    table = colour_module.bin_table(lut)
    if table is None:
        path, table = PATH_SCALAR, np.zeros(96, np.float32)
    return _colour_maps(path, image, lut, table, tile, factor, True, factor > 0, tiles, box)


SHAPES = [
    (1, 1), (3, 5), (7, 15),          # smaller than a tile (and some than a box cell)
    (8, 8), (16, 16),                 # exactly one tile of 8 / of 16
    (16, 32), (8, 40),                # tiles cover every column: the bottom tile
                                      # row's last vector block would read past the image
    (17, 33), (31, 47),               # odd: partial tiles and cells everywhere
    (24, 107),                        # factor 2: 3 whole blocks + 5 pixels per row
    (45, 143),                        # factor 4: 2 whole blocks + 3 pixels per row
    (50, 71),                         # factor 1: 4 whole blocks + 7 pixels per row
    (67, 200),
]


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("tile, factor", [
    (8, 2), (16, 2), (8, 4), (16, 1), (8, 0), (16, 4), (32, 2), (64, 2),
    (4, 2), (12, 3), (5, 2), (6, 1), (1, 4), (2, 0),
])
@pytest.mark.parametrize("kind", ["bins32", "random"])
def test_random_images_match_numpy(path, shape, tile, factor, kind):
    rng = np.random.default_rng(shape[0] * 1000 + shape[1] + tile * 7 + factor)
    image = rng.integers(0, 256, shape + (3,), dtype=np.uint8)
    check(image, make_lut(kind, rng), tile, factor)


@pytest.mark.parametrize("kind", LUT_KINDS)
@pytest.mark.parametrize("tile", [1, 2, 4, 8, 16, 32, 64, 5, 12])
def test_every_lut_kind_and_tile(path, kind, tile):
    """Wide rows (many vector blocks) with odd widths: tails of whole tiles
    after the last 16-pixel block, and a partial tile past them."""
    rng = np.random.default_rng(tile * 31 + LUT_KINDS.index(kind))
    for shape in [(70, 251), (64, 64 * 5), (9, 163)]:
        image = rng.integers(0, 256, shape + (3,), dtype=np.uint8)
        check(image, make_lut(kind, rng), tile, 2)


@pytest.mark.parametrize("asked", [PATH_AVX512, PATH_AVX2])
def test_bin_table_path_is_taken_only_for_binned_luts(monkeypatch, asked):
    """A vector path is taken exactly for luts constant on aligned runs of 8
    values, and only the one this CPU's kernels have; any other lut, a path
    the CPU lacks, or the scalar path asked for, gives the scalar path."""
    rng = np.random.default_rng(5)
    image = rng.integers(0, 256, (40, 100, 3), dtype=np.uint8)
    vector = asked if colour_module.TILE_PATH == asked else PATH_SCALAR
    for bins in BINNED + [2, 4]:
        lut = binned_lut(rng, bins)
        np.testing.assert_array_equal(colour_module.bin_table(lut),
                                      lut[:, ::8].reshape(-1))
        assert tile_path(monkeypatch, image, lut, 8, 2, asked) == vector
        assert tile_path(monkeypatch, image, lut, 8, 2, PATH_SCALAR) == PATH_SCALAR
    for bins in NOT_BINNED:
        assert colour_module.bin_table(binned_lut(rng, bins)) is None
        assert tile_path(monkeypatch, image, binned_lut(rng, bins), 8, 2, asked) == PATH_SCALAR
    assert tile_path(monkeypatch, image, random_lut(rng), 16, 0, asked) == PATH_SCALAR
    for c, v in [(0, 1), (1, 255), (2, 100)]:     # one value off its run
        lut = binned_lut(rng)
        lut[c, v] += 1
        assert colour_module.bin_table(lut) is None
        assert tile_path(monkeypatch, image, lut, 8, 2, asked) == PATH_SCALAR
    lut = binned_lut(rng)
    lut[1, 77] = np.nan                             # NaN equals nothing: scalar
    assert colour_module.bin_table(lut) is None
    assert tile_path(monkeypatch, image, lut, 8, 2, asked) == PATH_SCALAR
    # The kernel itself: a path whose instructions the CPU lacks is pruned.
    lut = binned_lut(rng)
    tiles = np.empty((5, 12), np.float32)
    box = np.empty((20, 50, 3), np.float32)
    assert kernel_maps(asked, image, lut, 8, 2, tiles, box) == vector


@pytest.mark.parametrize("shape", [(16, 32), (37, 131), (48, 100), (70, 251), (33, 1344)])
@pytest.mark.parametrize("tile", [1, 4, 5, 8, 16, 32, 64])
@pytest.mark.parametrize("kind", ["bins32", "random"])
def test_every_path_adds_in_the_documented_order(path, shape, tile, kind):
    """Every path's sums are the float32 sums of naive_bin_order_tile_sums,
    bit for bit (so the AVX-512, AVX2 and per-pixel paths agree, and a CPU
    without a vector path gives the same sums); whole vector blocks, groups
    of four columns and single columns alike, for a lut with a bin table and
    for one without (which only the per-pixel lookups serve)."""
    rng = np.random.default_rng(shape[1] * 7 + tile)
    image = rng.integers(0, 256, shape + (3,), dtype=np.uint8)
    lut = make_lut(kind, rng)
    tiles, _ = colour_maps(image, lut, tile, 0)
    np.testing.assert_array_equal(tiles, naive_bin_order_tile_sums(image, lut, tile))


def test_colour_maps_takes_the_vector_path(monkeypatch):
    """colour_maps itself asks for the vector path where the CPU has it."""
    taken = []

    def spy(*args):
        taken.append(_colour_maps(*args))

    monkeypatch.setattr(colour_module, "_colour_maps", spy)
    rng = np.random.default_rng(2)
    image = rng.integers(0, 256, (32, 64, 3), dtype=np.uint8)
    colour_maps(image, binned_lut(rng), 16, 2)
    colour_maps(image, random_lut(rng), 16, 2)
    assert taken == [colour_module.TILE_PATH, PATH_SCALAR]


def test_haswell_target_takes_the_avx2_path(tmp_path):
    """Compiled for a CPU with AVX2 and no AVX-512 (NUMBA_CPU_NAME=haswell with
    an empty NUMBA_CPU_FEATURES: Haswell's own features; with the variable
    unset Numba would add the host's), the AVX-512 branch is pruned: asked
    for, it gives the scalar path; the AVX2 path runs and adds in the bin
    paths' order."""
    script = textwrap.dedent("""
        import sys
        import numpy as np
        import fastdet.kernels.colour as colour
        assert not colour.HAVE_AVX512BW and colour.TILE_PATH == colour.PATH_AVX2
        rng = np.random.default_rng(1)
        image = rng.integers(0, 256, (37, 131, 3), dtype=np.uint8)
        lut = np.ascontiguousarray(rng.normal(size=(3, 32)).astype(np.float32)[
            :, np.arange(256) // 8])
        tiles = np.empty((37 // 8, 131 // 8), np.float32)
        box = np.empty((18, 65, 3), np.float32)
        table = colour.bin_table(lut)
        for asked, taken in ((colour.PATH_AVX512, colour.PATH_SCALAR),
                             (colour.PATH_AVX2, colour.PATH_AVX2)):
            path = colour._colour_maps(asked, image, lut, table, 8, 2, True, True, tiles, box)
            assert path == taken, (asked, path)
        np.save(sys.argv[1], tiles)
    """)
    environment = dict(os.environ, NUMBA_CPU_NAME="haswell", NUMBA_CPU_FEATURES="",
                       NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    out = tmp_path / "tiles.npy"
    subprocess.run([sys.executable, "-c", script, str(out)], check=True, env=environment,
                   timeout=600)
    rng = np.random.default_rng(1)
    image = rng.integers(0, 256, (37, 131, 3), dtype=np.uint8)
    lut = np.ascontiguousarray(rng.normal(size=(3, 32)).astype(np.float32)[:, np.arange(256) // 8])
    np.testing.assert_array_equal(np.load(out), naive_bin_order_tile_sums(image, lut, 8))


def test_avx512_target_compiles_the_avx512_path(tmp_path):
    """Compiled for an AVX-512 CPU (NUMBA_CPU_NAME=skylake-avx512 with its own
    features), the kernel takes the AVX-512 branch and its code uses
    vpermi2ps on 512-bit registers; compiled only, not run, so that machines
    without AVX-512 still check that the branch compiles."""
    script = textwrap.dedent("""
        import numpy as np
        from numba import typeof
        import fastdet.kernels.colour as colour
        assert colour.TILE_PATH == colour.PATH_AVX512 and not colour._CAN_AVX2
        args = (np.int64(colour.PATH_AVX512), np.zeros((16, 64, 3), np.uint8),
                np.zeros((3, 256), np.float32), np.zeros(96, np.float32), np.int64(16),
                np.int64(2), True, True, np.zeros((1, 4), np.float32),
                np.zeros((8, 32, 3), np.float32))
        kernel = colour._colour_maps
        kernel.compile(tuple(typeof(a) for a in args))
        code = kernel.inspect_asm(kernel.signatures[0])
        assert "zmm" in code and ("vpermi2ps" in code or "vpermt2ps" in code)
    """)
    environment = dict(os.environ, NUMBA_CPU_NAME="skylake-avx512", NUMBA_CPU_FEATURES="",
                       NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    subprocess.run([sys.executable, "-c", script], check=True, env=environment, timeout=600)


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("factor", [1, 2, 3, 4])
def test_box_alone_matches_numpy(shape, factor):
    rng = np.random.default_rng(shape[0] + shape[1] * 31 + factor)
    image = rng.integers(0, 256, shape + (3,), dtype=np.uint8)
    check(image, None, 8, factor)


def test_extreme_values(path):
    """All-255 pixels (largest sums) and all-0 pixels, next to each other."""
    image = np.zeros((40, 96, 3), np.uint8)
    image[:, 48:] = 255
    image[::3, ::5, 1] = 255
    lut = np.linspace(-1e3, 1e3, 768, dtype=np.float32).reshape(3, 256)
    binned = np.ascontiguousarray(lut[:, np.arange(256) & ~7])
    for tile, factor in [(8, 2), (16, 4), (8, 1), (5, 3)]:
        check(image, lut, tile, factor)
        check(image, binned, tile, factor)


@pytest.mark.parametrize("kind", ["bins32", "random"])
def test_each_output_is_independent_of_the_other(path, kind):
    """Tile sums and box mean computed together equal each computed alone
    (the two passes are interleaved by bands of rows)."""
    rng = np.random.default_rng(7)
    lut = make_lut(kind, rng)
    for shape in [(37, 131), (9, 70), (70, 9), (100, 64)]:
        image = rng.integers(0, 256, shape + (3,), dtype=np.uint8)
        for tile, factor in [(8, 2), (16, 2), (8, 4), (32, 1), (16, 3), (5, 2)]:
            tiles, box = colour_maps(image, lut, tile, factor)
            np.testing.assert_array_equal(tiles, colour_maps(image, lut, tile, 0)[0])
            np.testing.assert_array_equal(box, colour_maps(image, None, tile, factor)[1])


def test_non_contiguous_image_and_lut(path):
    rng = np.random.default_rng(3)
    big = rng.integers(0, 256, (80, 150, 3), dtype=np.uint8)
    view = big[5:70:2, 3:140]                       # strided rows
    lut_view = rng.normal(size=(256, 3)).astype(np.float32).T   # Fortran-ordered (3, 256)
    assert not view.flags.c_contiguous and not lut_view.flags.c_contiguous
    check(view, lut_view, 8, 2)
    check(view, lut_view.astype(np.float64), 16, 4)   # float64 LUT is converted
    binned_view = np.asfortranarray(binned_lut(rng))
    assert not binned_view.flags.c_contiguous
    check(view, binned_view, 8, 2)
    check(view, binned_view.astype(np.float64), 16, 4)


def test_lut_none_and_factor_zero_skip_both():
    image = np.full((16, 16, 3), 9, np.uint8)
    tiles, box = colour_maps(image, None, 8, 0)
    assert tiles.shape == (0, 0) and box.shape == (0, 0, 3)


@pytest.mark.parametrize("binned", [False, True])
@pytest.mark.parametrize("tile", [8, 16])
def test_tile_sums_read_the_right_pixel_and_channel(path, binned, tile):
    """One marked pixel per tile, at a random place and channel: its weight
    (unique per channel and value, or per channel and bin of 8 values, exact
    in float32) lands in its tile only."""
    th, tw = 5, 9
    image = np.zeros((th * tile + 3, tw * tile + 5, 3), np.uint8)
    lut = (np.arange(768, dtype=np.float32) + 1).reshape(3, 256)
    if binned:
        lut = np.ascontiguousarray(lut[:, np.arange(256) & ~7])
        lut[:, :8] = 0                              # unmarked pixels weigh 0
    else:
        lut[:, 0] = 0
    low = 8 if binned else 1
    expected = np.zeros((th, tw), np.float32)
    rng = np.random.default_rng(11 + tile)
    for ty in range(th):
        for tx in range(tw):
            dy, dx, c = rng.integers(0, tile), rng.integers(0, tile), rng.integers(0, 3)
            value = rng.integers(low, 256)
            image[ty * tile + dy, tx * tile + dx, c] = value
            expected[ty, tx] = lut[c, value]
    for factor in (0, 2):
        np.testing.assert_array_equal(colour_maps(image, lut, tile, factor)[0], expected)


@pytest.mark.parametrize("shape", [(1, 1), (7, 15), (17, 33), (45, 143), (67, 200)])
@pytest.mark.parametrize("tile, factor", [(8, 2), (16, 4), (8, 1), (5, 3), (12, 2), (32, 0)])
@pytest.mark.parametrize("kind", ["bins32", "random"])
def test_kernel_writes_every_output_element(path, shape, tile, factor, kind):
    """colour_maps hands the kernel uninitialised (np.empty) outputs, so the
    kernel must write every element: start from NaN and look for leftovers."""
    rng = np.random.default_rng(shape[1] + tile)
    image = rng.integers(0, 256, shape + (3,), dtype=np.uint8)
    lut = make_lut(kind, rng)
    tiles = np.full((shape[0] // tile, shape[1] // tile), np.nan, np.float32)
    box = np.full((shape[0] // factor, shape[1] // factor, 3) if factor else (0, 0, 3), np.nan,
                  np.float32)
    kernel_maps(path, image, lut, tile, factor, tiles, box)
    assert not np.isnan(tiles).any() and not np.isnan(box).any()
    expected_tiles, expected_box = check(image, lut, tile, factor)
    np.testing.assert_array_equal(tiles, expected_tiles)
    np.testing.assert_array_equal(box, expected_box)


@pytest.fixture(scope="module")
def real_hls(data_dir):
    frame = cv2.imread(str(data_dir / "test_images" / "test1.jpg"))
    assert frame is not None, "test_images/test1.jpg is unreadable"
    return cv2.cvtColor(frame, cv2.COLOR_BGR2HLS)


@pytest.mark.parametrize("size, rows", [
    ((1697, 225), (360, 540)),
    ((417, 225), (360, 660)),
    ((721, 145), (380, 525)),
    ((640, 129), (400, 529)),
    ((99, 37), (400, 500)),
])
@pytest.mark.parametrize("tile, factor", [(8, 2), (16, 2), (32, 2), (64, 2), (32, 4), (8, 1)])
@pytest.mark.parametrize("kind", ["bins32", "bins16", "random"])
def test_real_image_matches_numpy(path, real_hls, size, rows, tile, factor, kind):
    """The detector's use: HLS crops resized to each search scale, with the
    detector's kind of lut (per-channel bin weights expanded to all 256
    values) and others."""
    image = cv2.resize(real_hls[rows[0]:rows[1]], size)
    check(image, make_lut(kind, np.random.default_rng(0)), tile, factor)


def test_rows_without_tile_sums_need_whole_boxes_only():
    """Without a lut there are no tile sums: rows cut at multiples of the box factor
    (not of the tile) are allowed, and give the whole image's boxes."""
    from fastdet.kernels.colour import ColourMapRows

    rng = np.random.default_rng(5)
    image = rng.integers(0, 256, (96, 40, 3), dtype=np.uint8)
    whole = ColourMapRows(image.shape, None, 32, 4, (None, None))
    whole(image, 0, 96)
    parts = ColourMapRows(image.shape, None, 32, 4, (None, None))
    for top in range(0, 96, 24):
        parts(image, top, top + 24)
    np.testing.assert_array_equal(parts.box, whole.box)
    with pytest.raises(ValueError, match="cut tiles"):
        parts(image, 2, 24)
    with_tiles = ColourMapRows(image.shape, binned_lut(rng), 32, 4, (None, None))
    with pytest.raises(ValueError, match="cut tiles"):
        with_tiles(image, 0, 24)
