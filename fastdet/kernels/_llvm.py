"""Small llvmlite helpers shared by the kernels' vector intrinsics.

The intrinsics (``hog``, ``resize``, ``colour``, ``convert``, ``score``) read
and write vectors at arbitrary element offsets of Numba arrays: a pointer to
element ``index`` cast to the vector type.  ``score``'s also broadcast scalars
and emit loops whose trip counts are only known at run time.  The ``HAVE_*``
flags say which x86 instruction sets those with target-specific paths may use.
Numba's on-disk cache is keyed on the files of the kernels that use them,
not on this one: after changing these, touch those modules.
"""

import platform

from llvmlite import ir


def load_vector(builder, data, index, vector_type, align=1):
    """Load a ``vector_type`` from element ``index`` of the array data pointer ``data``."""
    pointer = builder.bitcast(builder.gep(data, [index]), vector_type.as_pointer())
    return builder.load(pointer, align=align, typ=vector_type)


def store_vector(builder, value, data, index, align=1):
    """Store the vector ``value`` at element ``index`` of the array data pointer ``data``."""
    pointer = builder.bitcast(builder.gep(data, [index]), value.type.as_pointer())
    builder.store(value, pointer, align=align)


def box_sums(builder, rows, factor, channels):
    """Sums of ``factor x factor`` pixel boxes, as 16-bit lanes.

    ``rows`` are ``factor`` byte vectors, the same run of
    ``factor * n * channels`` bytes (``n`` output pixels of interleaved
    channels) from consecutive image rows.  Each is widened to 16 bits and
    the rows added; constant shuffles then pick each output value's
    ``factor`` column sums, which are added: lane ``channels * o + c`` holds
    output pixel ``o``'s channel ``c``.  Sums of up to 256 bytes fit.
    """
    n_in = rows[0].type.count
    n_out = n_in // factor
    words_in = ir.VectorType(ir.IntType(16), n_in)
    column = None
    for row in rows:
        wide = builder.zext(row, words_in)
        column = wide if column is None else builder.add(column, wide)
    undef = ir.Constant(words_in, ir.Undefined)
    mask_type = ir.VectorType(ir.IntType(32), n_out)
    total = None
    for dx in range(factor):
        mask = [channels * (factor * (k // channels) + dx) + k % channels for k in range(n_out)]
        pick = builder.shuffle_vector(column, undef, ir.Constant(mask_type, mask))
        total = pick if total is None else builder.add(total, pick)
    return total


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


def _has_feature(name):
    """Whether the CPU Numba compiles for has ``name``.

    That is the host unless ``NUMBA_CPU_NAME`` / ``NUMBA_CPU_FEATURES`` select
    another target (portable caches, containers): then only features listed
    in ``NUMBA_CPU_FEATURES`` count, and with a CPU name alone none do.
    """
    if platform.machine().lower() not in ("x86_64", "amd64"):
        return False
    from numba.core import config
    if config.CPU_FEATURES:
        return f"+{name}" in config.CPU_FEATURES.split(",")
    if config.CPU_NAME:
        return False
    try:
        from llvmlite import binding
        return f"+{name}" in binding.get_host_cpu_features().flatten().split(",")
    except Exception:  # noqa: BLE001 - no feature list: take the portable path
        return False


#: Instruction sets of the CPU Numba compiles for, which pick the kernels'
#: vector paths (resize's horizontal pass, colour's bin-table tile sums).
HAVE_SSSE3 = _has_feature("ssse3")
HAVE_AVX2 = HAVE_SSSE3 and _has_feature("avx2")
HAVE_AVX512BW = HAVE_AVX2 and _has_feature("avx512f") and _has_feature("avx512bw")
