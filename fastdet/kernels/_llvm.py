"""Small llvmlite helpers shared by the kernels' vector intrinsics.

The intrinsics (``hog``, ``resize``, ``colour``, ``convert``) read and write
vectors at arbitrary element offsets of Numba arrays; these two functions are
that one pattern: a pointer to element ``index`` cast to the vector type.
Numba's on-disk cache is keyed on the files of the kernels that use them,
not on this one: after changing these, touch those modules.
"""


def load_vector(builder, data, index, vector_type, align=1):
    """Load a ``vector_type`` from element ``index`` of the array data pointer ``data``."""
    pointer = builder.bitcast(builder.gep(data, [index]), vector_type.as_pointer())
    return builder.load(pointer, align=align, typ=vector_type)


def store_vector(builder, value, data, index, align=1):
    """Store the vector ``value`` at element ``index`` of the array data pointer ``data``."""
    pointer = builder.bitcast(builder.gep(data, [index]), value.type.as_pointer())
    builder.store(value, pointer, align=align)
