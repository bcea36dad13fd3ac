"""Calling a kernel's own compiled code from another kernel, by its address.

When one ``@njit`` kernel calls another, Numba links the callee's LLVM
module into the caller's and optimises and compiles the whole of it to
machine code again: the callee's code is built twice, once on its own and
once inside each caller.  For :mod:`fastdet.kernels.band`, whose one call
runs the cell, colour-map and scoring kernels of a scale, that second build
cost about 1.2 s of every cold start (Intel Xeon, 2026-12-02: 3.9 s for the
band kernel against 2.7 s for the three on their own).  Called through
:func:`call_compiled`, a caller holds only an indirect call: it compiles in
a fraction of a second, and the callees are the machine code their own
cache entries already hold.

The address is a run-time argument, never a constant in the caller's
code, so the caller's cache entry stays valid in every process (the
callee's code lies at another address in each).
"""

from __future__ import annotations

from numba import types
from numba.core import cgutils
from numba.extending import intrinsic


@intrinsic
def call_compiled(typingctx, address, arguments, result):
    """``kernel(*arguments)`` for the kernel whose compiled code is at ``address``.

    Parameters
    ----------
    address : int
        :func:`compiled_address` of the kernel for exactly these argument types.
    arguments : tuple
        Its arguments.
    result : value of the kernel's return type
        Only its type is used (``None`` for a kernel that returns nothing).

    Returns
    -------
    What the kernel returns.  An exception it raises propagates, as from a
    direct call.
    """
    if not isinstance(address, types.Integer) or not isinstance(arguments, types.BaseTuple):
        return None
    argument_types = tuple(arguments.types)
    return_type = result

    def codegen(context, builder, signature, args):
        values = [builder.extract_value(args[1], k) for k in range(len(argument_types))]
        function_type = context.call_conv.get_function_type(return_type, argument_types)
        function = builder.inttoptr(args[0], function_type.as_pointer())
        status, value = context.call_conv.call_function(builder, function, return_type,
                                                        argument_types, values)
        with cgutils.if_unlikely(builder, status.is_error):
            context.call_conv.return_status_propagate(builder, status)
        return value

    return return_type(address, arguments, result), codegen


def compiled_address(kernel, arguments):
    """``(address, return_type)`` of ``kernel``'s compiled code for ``arguments``' types.

    Loads it from the cache, or compiles it, as a call from Python with these
    arguments would; :func:`call_compiled` then calls it.

    Parameters
    ----------
    kernel : numba dispatcher
    arguments : tuple
        Arguments as a call from Python would pass them.

    Returns
    -------
    address : int
    return_type : numba type
    """
    signature = tuple(kernel.typeof_pyval(argument) for argument in arguments)
    compiled = kernel.overloads.get(signature)
    if compiled is None:
        kernel.compile(signature)
        compiled = kernel.overloads[signature]
    address = compiled.library.get_pointer_to_function(compiled.fndesc.llvm_func_name)
    return address, compiled.signature.return_type
