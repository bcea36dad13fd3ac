"""``flat``: a C-contiguous array as one dimension, for the kernels, lowered inline.

Numba lowers ``array.reshape(n)`` through ``normalize_reshape_value``, a
function of its own compiled on first use in each process (it resolves a
``-1`` in the new shape), and ``ravel`` through ``reshape``: 0.11-0.13 s of
each compiling process's cold start (AMD EPYC, Zen 3), for views the
kernels only take of whole C-contiguous arrays.  :func:`flat` is lowered
straight into the calling kernel: the same data and owner, shape
``(size,)``, one item's stride.  Called from Python it is NumPy's
``reshape``.

Only C-layout arrays are accepted (any other is a typing error), so the
view needs no run-time check.  Numba's on-disk cache is keyed on the files
of the kernels that call it, not on this one: after changing the lowering,
touch those modules.
"""

from __future__ import annotations

from numba import types
from numba.core import cgutils
from numba.core.imputils import impl_ret_borrowed
from numba.extending import lower_builtin, type_callable
from numba.np.arrayobj import make_array, populate_array


def flat(array):
    """``array.reshape(array.size)``: a 1-D view of a C-contiguous array."""
    return array.reshape(array.size)


@type_callable(flat)
def _type_flat(context):
    def typer(array):
        if isinstance(array, types.Array) and array.layout == "C":
            return array.copy(ndim=1, layout="C")
        return None
    return typer


@lower_builtin(flat, types.Array)
def _lower_flat(context, builder, signature, args):
    source = make_array(signature.args[0])(context, builder, args[0])
    view = make_array(signature.return_type)(context, builder)
    populate_array(view, data=source.data,
                   shape=cgutils.pack_array(builder, [source.nitems]),
                   strides=cgutils.pack_array(builder, [source.itemsize]),
                   itemsize=source.itemsize, meminfo=source.meminfo, parent=source.parent)
    # A view: it holds a new reference to the source's owner.
    return impl_ret_borrowed(context, builder, signature.return_type, view._getvalue())
