"""Small llvmlite helpers shared by the kernels' vector intrinsics.

The intrinsics (``hog``, ``resize``, ``colour``, ``convert``, ``score``) read
and write vectors at arbitrary element offsets of Numba arrays: a pointer to
element ``index`` cast to the vector type.  ``score``'s also broadcast scalars
and emit loops whose trip counts are only known at run time.
Numba's on-disk cache is keyed on the files of the kernels that use them,
not on this one: after changing these, touch those modules.
"""

from llvmlite import ir


def load_vector(builder, data, index, vector_type, align=1):
    """Load a ``vector_type`` from element ``index`` of the array data pointer ``data``."""
    pointer = builder.bitcast(builder.gep(data, [index]), vector_type.as_pointer())
    return builder.load(pointer, align=align, typ=vector_type)


def store_vector(builder, value, data, index, align=1):
    """Store the vector ``value`` at element ``index`` of the array data pointer ``data``."""
    pointer = builder.bitcast(builder.gep(data, [index]), value.type.as_pointer())
    builder.store(value, pointer, align=align)


def splat(builder, value, vector_type):
    """``value`` (a scalar of the element type) in every lane of ``vector_type``."""
    undef = ir.Constant(vector_type, ir.Undefined)
    lane0 = builder.insert_element(undef, value, ir.Constant(ir.IntType(32), 0))
    return builder.shuffle_vector(lane0, undef, ir.Constant(
        ir.VectorType(ir.IntType(32), vector_type.count), [0] * vector_type.count))


def counted_loop(builder, count, initial, body):
    """Emit ``for i in range(count)`` carrying ``initial`` values through ``body``.

    ``body(i, values)`` emits one iteration and returns the next values; the
    values after the last iteration are returned.  A top-tested loop, so a
    zero ``count`` runs no iteration.
    """
    i64 = ir.IntType(64)
    before = builder.block
    head = builder.append_basic_block("loop_head")
    loop = builder.append_basic_block("loop_body")
    done = builder.append_basic_block("loop_done")
    builder.branch(head)
    builder.position_at_end(head)
    index = builder.phi(i64)
    values = [builder.phi(value.type) for value in initial]
    index.add_incoming(ir.Constant(i64, 0), before)
    for phi, value in zip(values, initial):
        phi.add_incoming(value, before)
    builder.cbranch(builder.icmp_unsigned("<", index, count), loop, done)
    builder.position_at_end(loop)
    following = body(index, values)
    latch = builder.block
    index.add_incoming(builder.add(index, ir.Constant(i64, 1)), latch)
    for phi, value in zip(values, following):
        phi.add_incoming(value, latch)
    builder.branch(head)
    builder.position_at_end(done)
    return values
