"""``empty``, ``zeros`` and ``full`` for the kernels: NumPy's, allocated inline when compiled.

Numba compiles ``np.empty``, ``np.zeros`` and ``np.full`` as implementations of their
own, once for every shape type, dtype and set of the calling kernel's jit
flags: on a cold start that was 39 compiles and 2.2 s (with their zero
fill) of the 20 s a detection's kernels took to compile (AMD EPYC, Zen 3),
paid again by each of the two compiling processes.  Here the allocation is lowered
straight into the calling kernel with Numba's own array allocator (the code
``np.empty`` itself ends in); ``zeros`` adds a ``memset`` and ``full`` a fill
loop: the same arrays, without the separate compiles.  Called from Python,
they are NumPy's.

The lowering uses two internals of ``numba.np.arrayobj``
(``_empty_nd_impl``, ``_parse_shape``).  Where they are missing (another
Numba), they compile as ``np.empty``, ``np.zeros`` and ``np.full``.
"""

from __future__ import annotations

import numpy as np
from numba import types
from numba.core import cgutils
from numba.extending import lower_builtin, overload, type_callable

try:
    from numba.np.arrayobj import _empty_nd_impl, _parse_shape, ty_parse_dtype, ty_parse_shape
except ImportError:  # pragma: no cover - another Numba: the overloads below
    _empty_nd_impl = None


def empty(shape, dtype=float):
    """``np.empty(shape, dtype)``, C order."""
    return np.empty(shape, dtype)


def zeros(shape, dtype=float):
    """``np.zeros(shape, dtype)``, C order."""
    return np.zeros(shape, dtype)


def full(shape, fill_value, dtype):
    """``np.full(shape, fill_value, dtype)``, C order (the dtype is required)."""
    return np.full(shape, fill_value, dtype)


def _array_type(shape, dtype):
    """The C-order array type ``np.empty(shape, dtype)`` returns, or None."""
    if (dtype is None or isinstance(dtype, (types.Omitted, types.NoneType))
            or (isinstance(dtype, types.Function) and dtype.typing_key is float)):
        nb_dtype = types.float64
    else:
        nb_dtype = ty_parse_dtype(dtype)
    ndim = ty_parse_shape(shape)
    if nb_dtype is None or ndim is None:
        return None
    return types.Array(nb_dtype, ndim, "C")


def _lowering(zero):
    def lower(context, builder, sig, args):
        shapes = _parse_shape(context, builder, sig.args[0], args[0])
        array = _empty_nd_impl(context, builder, sig.return_type, shapes)
        if zero:
            cgutils.memset(builder, array.data, builder.mul(array.itemsize, array.nitems), 0)
        return array._getvalue()
    return lower


if _empty_nd_impl is not None:
    for _function, _zero in ((empty, False), (zeros, True)):
        @type_callable(_function)
        def _type(context):
            def typer(shape, dtype=None):
                return _array_type(shape, dtype)
            return typer

        lower_builtin(_function, types.Any)(_lowering(_zero))
        lower_builtin(_function, types.Any, types.Any)(_lowering(_zero))

    @type_callable(full)
    def _type_full(context):
        def typer(shape, fill_value, dtype):
            return _array_type(shape, dtype)
        return typer

    @lower_builtin(full, types.Any, types.Any, types.Any)
    def _lower_full(context, builder, sig, args):
        shapes = _parse_shape(context, builder, sig.args[0], args[0])
        array = _empty_nd_impl(context, builder, sig.return_type, shapes)
        value = context.cast(builder, args[1], sig.args[1], sig.return_type.dtype)
        with cgutils.for_range(builder, array.nitems) as loop:
            builder.store(value, builder.gep(array.data, [loop.index]))
        return array._getvalue()
else:  # pragma: no cover
    @overload(empty)
    def _empty_overload(shape, dtype=float):
        def impl(shape, dtype=float):
            return np.empty(shape, dtype)
        return impl

    @overload(zeros)
    def _zeros_overload(shape, dtype=float):
        def impl(shape, dtype=float):
            return np.zeros(shape, dtype)
        return impl

    @overload(full)
    def _full_overload(shape, fill_value, dtype):
        def impl(shape, fill_value, dtype):
            return np.full(shape, fill_value, dtype)
        return impl
