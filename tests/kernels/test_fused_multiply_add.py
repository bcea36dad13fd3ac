"""``fused_multiply_add``: llvm.fma, or its float64 emulation where the CPU has no FMA."""

import numpy as np
import pytest
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

from fastdet.kernels._llvm import fused_multiply_add, load_vector, store_vector
from naive import naive_fma_float32

LANES = 4


def _kernel(emulate):
    @intrinsic
    def fma_block(typingctx, a, b, c, out, start):
        def codegen(context, builder, signature, args):
            vector = ir.VectorType(ir.FloatType(), LANES)
            data = [context.make_array(signature.args[k])(context, builder, args[k]).data
                    for k in range(4)]
            index = context.cast(builder, args[4], signature.args[4], types.int64)
            x, y, z = (load_vector(builder, d, index, vector) for d in data[:3])
            store_vector(builder, fused_multiply_add(builder, x, y, z, emulate=emulate),
                         data[3], index)
            return context.get_dummy_value()

        return types.void(a, b, c, out, start), codegen

    @njit
    def run(a, b, c, out):
        for start in range(0, a.size, LANES):
            fma_block(a, b, c, out, start)

    return run


KERNELS = {"llvm.fma": _kernel(False), "float64 emulation": _kernel(True)}


def _same_bits(x, y):
    """Equal bit for bit, any two NaNs counting as equal."""
    return (x.view(np.uint32) == y.view(np.uint32)) | (np.isnan(x) & np.isnan(y))


def _cases(rng, n):
    """Products that nearly cancel the addend, ties and midpoints, tiny and huge values."""
    a = rng.standard_normal(n).astype(np.float32)
    b = rng.standard_normal(n).astype(np.float32)
    c = (rng.standard_normal(n) * 10.0 ** rng.integers(-12, 12, n)).astype(np.float32)
    near = n // 4
    # c close to -a * b: the sum cancels to a few bits; the float32 product alone is wrong there.
    c[:near] = -(a[:near] * b[:near]) * (1 + rng.integers(-3, 4, near) * np.float32(2 ** -23))
    # Products whose low 24 bits are exactly half a float32 step: ties decided by c's sign.
    a[near:2 * near] = 1 + np.float32(2 ** -12)
    b[near:2 * near] = (1 + rng.integers(1, 2 ** 11, near) * 2.0 ** -11 + 2.0 ** -12).astype(
        np.float32)
    c[near:2 * near] = (rng.choice([-1, 1], near) * 2.0 ** rng.integers(-80, -30, near)).astype(
        np.float32)
    return a, b, c


@pytest.mark.parametrize("path", list(KERNELS))
def test_rounds_once_like_exact_arithmetic(path):
    rng = np.random.default_rng(7)
    a, b, c = _cases(rng, 4000)
    out = np.empty_like(a)
    KERNELS[path](a, b, c, out)
    expected = naive_fma_float32(a, b, c)
    np.testing.assert_array_equal(out.view(np.uint32), expected.view(np.uint32))
    # The cases are ones where rounding twice would differ.
    twice = (a * b + c).astype(np.float32)
    assert np.count_nonzero(twice != expected) > 500


@pytest.mark.parametrize("path", list(KERNELS))
def test_special_values(path):
    inf, nan, big = np.float32(np.inf), np.float32(np.nan), np.finfo(np.float32).max
    tiny = np.float32(np.finfo(np.float32).smallest_subnormal)
    a = np.array([inf, 0, 1, -0.0, big, big, tiny, 1, nan, 2, -1, 3e-39], np.float32)
    b = np.array([1, inf, 1, 0, 2, -1, tiny, -1, 1, 3, -0.0, 7e-1], np.float32)
    c = np.array([1, 1, -inf, -0.0, 0, big, tiny, 1, 1, nan, -0.0, -2e-39], np.float32)
    out = np.empty_like(a)
    KERNELS[path](a, b, c, out)
    expected = naive_fma_float32(a, b, c)
    assert _same_bits(out, expected).all(), (out, expected)


def test_the_two_paths_agree_bit_for_bit_on_random_floats():
    rng = np.random.default_rng(11)
    n = 1 << 16
    # Random bit patterns: every exponent, subnormals, infinities and NaN included.
    a, b, c = (rng.integers(0, 2 ** 32, n, dtype=np.uint64).astype(np.uint32).view(np.float32)
               for _ in range(3))
    outs = {}
    for path, kernel in KERNELS.items():
        outs[path] = np.empty_like(a)
        kernel(a, b, c, outs[path])
    fused, emulated = outs.values()
    assert _same_bits(fused, emulated).all()


def test_fma_instructions_are_found_per_target():
    from fastdet.kernels._llvm import fma_in_hardware

    assert fma_in_hardware("haswell", "") is True
    assert fma_in_hardware("sandybridge", "") is False   # AVX, but no FMA
    assert fma_in_hardware("generic", "") is False


def test_the_flag_agrees_with_the_probe_on_this_target():
    from fastdet.kernels import _llvm

    # The x86 flag comes from LLVM's feature list; the probe asks the code generator.
    assert _llvm.HAVE_FMA == _llvm.fma_in_hardware()


def test_other_architectures_keep_only_the_fma_probe(monkeypatch):
    from fastdet.kernels import _llvm

    monkeypatch.setattr(_llvm.platform, "machine", lambda: "aarch64")
    found = _llvm._target_features(("ssse3", "avx2", "fma"))
    assert found == {"ssse3": False, "avx2": False, "fma": _llvm.fma_in_hardware()}
