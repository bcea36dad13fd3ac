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


def prefetch(builder, data, index):
    """Ask for the cache line of element ``index`` of ``data`` to be read (``llvm.prefetch``).

    A hint only: it never faults, so ``index`` may lie past the array.
    """
    i8p = ir.IntType(8).as_pointer()
    i32 = ir.IntType(32)
    pointer = builder.bitcast(builder.gep(data, [index]), i8p)
    name = "llvm.prefetch.p0i8"
    function = builder.module.globals.get(name)
    if function is None:
        function = ir.Function(builder.module,
                               ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32]), name)
    # read, keep in every cache level (locality 3), data cache
    builder.call(function, [pointer, ir.Constant(i32, 0), ir.Constant(i32, 3),
                            ir.Constant(i32, 1)])


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


def fused_multiply_add(builder, a, b, c, emulate=None):
    """``a * b + c`` rounded once, for float32 vectors, fast on every target.

    With FMA instructions this is ``llvm.fma``.  Without them (baseline
    x86-64, Intel before Haswell) LLVM would call libm's ``fmaf`` for every
    lane, which glibc then computes in software: 47 ns a lane against 2.2 ns
    for the code below; a frame took 394-405 ms against 32 with this and the
    cell kernel's ``llvm.fmuladd`` (NUMBA_CPU_NAME=generic
    with GLIBC_TUNABLES=glibc.cpu.hwcaps=-FMA,-AVX2,-FMA4 on an AMD EPYC, Zen
    3).  There it is emulated in float64, the same bits: the product of two
    float32 values is exact in float64, the sum's rounding error ``e`` is
    exact by TwoSum, and rounding the sum *to odd* (where ``e != 0`` and the
    float64 sum is even, its neighbour toward ``e``) before rounding to
    float32 gives the correctly rounded result, since float64 carries more
    than float32's 24 + 2 bits (Boldo and Melquiond, IEEE Trans. Computers
    57(4), 2008).  Infinities and NaN come out as ``llvm.fma`` gives them
    (their ``e`` is NaN and they are not adjusted).  ``emulate``: force the
    float64 form (True) or ``llvm.fma`` (False); default: by the target.
    """
    lanes = a.type.count
    if not (emulate if emulate is not None else not HAVE_FMA):
        fma = builder.module.declare_intrinsic(
            f"llvm.fma.v{lanes}f32", fnty=ir.FunctionType(a.type, [a.type] * 3))
        return builder.call(fma, [a, b, c])
    f64 = ir.VectorType(ir.DoubleType(), lanes)
    i64 = ir.VectorType(ir.IntType(64), lanes)
    wide_a, wide_b, wide_c = (builder.fpext(v, f64) for v in (a, b, c))
    product = builder.fmul(wide_a, wide_b)
    total = builder.fadd(product, wide_c)
    # TwoSum: total + error == product + c exactly.
    virtual_c = builder.fsub(total, product)
    error = builder.fadd(builder.fsub(product, builder.fsub(total, virtual_c)),
                         builder.fsub(wide_c, virtual_c))
    bits = builder.bitcast(total, i64)
    error_bits = builder.bitcast(error, i64)
    zero_i, one_i = ir.Constant(i64, [0] * lanes), ir.Constant(i64, [1] * lanes)
    inexact = builder.fcmp_ordered("!=", error, ir.Constant(f64, [0.0] * lanes))
    even = builder.icmp_signed("==", builder.and_(bits, one_i), zero_i)
    # Same sign: the exact sum lies beyond the float64 sum, away from zero.
    outward = builder.icmp_signed(">=", builder.xor(bits, error_bits), zero_i)
    step = builder.select(outward, one_i, ir.Constant(i64, [-1] * lanes))
    adjust = builder.select(builder.and_(inexact, even), step, zero_i)
    odd = builder.bitcast(builder.add(bits, adjust), f64)
    return builder.fptrunc(odd, a.type)


# Each probe is a tiny function whose machine code shows whether the target
# CPU has the feature: LLVM selects the feature's instruction (register width
# included) only when the target has it.  "min-legal-vector-width" keeps
# CPUs that prefer 256-bit vectors (Skylake-X) from splitting the 512-bit ones.
_PROBES = {
    "ssse3": ("declare <16 x i8> @llvm.abs.v16i8(<16 x i8>, i1)\n"
              "define void @probe(<16 x i8>* %p) {\n"
              "  %a = load <16 x i8>, <16 x i8>* %p\n"
              "  %r = call <16 x i8> @llvm.abs.v16i8(<16 x i8> %a, i1 false)\n"
              "  store <16 x i8> %r, <16 x i8>* %p\n  ret void\n}\n", "pabsb"),
    "avx2": ("define void @probe(<8 x i32>* %p) {\n"
             "  %a = load <8 x i32>, <8 x i32>* %p\n  %r = add <8 x i32> %a, %a\n"
             "  store <8 x i32> %r, <8 x i32>* %p\n  ret void\n}\n", "vpaddd\t%ymm"),
    "fma": ("declare float @llvm.fma.f32(float, float, float)\n"
            "define float @probe(float %a, float %b, float %c) {\n"
            "  %r = call float @llvm.fma.f32(float %a, float %b, float %c)\n"
            "  ret float %r\n}\n", "vfmadd"),
    "avx512f": ("define void @probe(<16 x i32>* %p) #0 {\n"
                "  %a = load <16 x i32>, <16 x i32>* %p\n  %r = add <16 x i32> %a, %a\n"
                "  store <16 x i32> %r, <16 x i32>* %p\n  ret void\n}\n"
                'attributes #0 = { "min-legal-vector-width"="512" }\n', "vpaddd\t%zmm"),
    "avx512bw": ("define void @probe(<32 x i16>* %p) #0 {\n"
                 "  %a = load <32 x i16>, <32 x i16>* %p\n  %r = add <32 x i16> %a, %a\n"
                 "  store <32 x i16> %r, <32 x i16>* %p\n  ret void\n}\n"
                 'attributes #0 = { "min-legal-vector-width"="512" }\n', "vpaddw\t%zmm"),
}


def _target_features(names):
    """Which of the features ``names`` the CPU Numba compiles for has.

    That is the host CPU unless ``NUMBA_CPU_NAME`` / ``NUMBA_CPU_FEATURES``
    select another target (portable caches, tests of the other paths).  Numba
    then compiles for that CPU name with the features of
    ``NUMBA_CPU_FEATURES`` if set (empty: the CPU name's own features) and
    the *host's* features otherwise, so ``NUMBA_CPU_NAME=haswell`` alone still
    uses AVX-512 on an AVX-512 host.  Flags are never taken from a vendor or
    model name: for the host they are LLVM's host feature list; for another
    target LLVM itself is asked, by compiling a probe per feature for the same
    CPU name and feature string as Numba and looking for the feature's
    instruction in the machine code.
    """
    if platform.machine().lower() not in ("x86_64", "amd64"):
        # No x86 vector path applies; fused multiply-adds may still be
        # instructions (every ARMv8 core has them).
        return {name: name == "fma" and fma_in_hardware() for name in names}
    from llvmlite import binding
    from numba.core import config
    try:
        host = binding.get_host_cpu_features().flatten()
    except Exception:  # noqa: BLE001 - no feature list: take the portable paths
        host = None
    if config.CPU_NAME is None and config.CPU_FEATURES is None:
        if host is None:
            return dict.fromkeys(names, False)
        listed = host.split(",")
        return {name: f"+{name}" in listed for name in names}
    machine = _target_machine()
    found = {}
    for name in names:
        source, instruction = _PROBES[name]
        found[name] = instruction in machine.emit_assembly(binding.parse_assembly(source))
    return found


def _target_machine(cpu=None, features=None):
    """An LLVM target machine for ``cpu`` and ``features``, by default Numba's:
    ``NUMBA_CPU_NAME`` or the host CPU, ``NUMBA_CPU_FEATURES`` or the host's
    features (none where the host lists none)."""
    from llvmlite import binding
    from numba.core import config
    binding.initialize_native_target()
    binding.initialize_native_asmprinter()
    if cpu is None:
        cpu = config.CPU_NAME or binding.get_host_cpu_name()
    if features is None:
        features = config.CPU_FEATURES
    if features is None:
        try:
            features = binding.get_host_cpu_features().flatten()
        except Exception:  # noqa: BLE001 - no feature list: the CPU name's own features
            features = ""
    return binding.Target.from_default_triple().create_target_machine(
        cpu=cpu, features=features, opt=0)


def fma_in_hardware(cpu=None, features=None):
    """Whether ``llvm.fma`` compiles to an instruction, not a call of libm's ``fmaf``.

    For Numba's target by default, or for ``cpu`` and ``features``
    (:func:`_target_machine`): the probe is compiled and its machine code
    searched for the call, which works on any architecture LLVM targets.
    """
    from llvmlite import binding
    machine = _target_machine(cpu, features)
    return "fmaf" not in machine.emit_assembly(binding.parse_assembly(_PROBES["fma"][0]))


_FOUND = _target_features(("ssse3", "avx2", "fma", "avx512f", "avx512bw"))

#: Instruction sets of the CPU Numba compiles for, which pick the kernels'
#: vector paths (resize's horizontal pass, colour's bin-table tile sums, the
#: lane count of hog's cell blocks).  Each implies the ones before it.
HAVE_SSSE3 = _FOUND["ssse3"]
HAVE_AVX2 = HAVE_SSSE3 and _FOUND["avx2"]
HAVE_AVX512F = HAVE_AVX2 and _FOUND["avx512f"]
HAVE_AVX512BW = HAVE_AVX512F and _FOUND["avx512bw"]
#: Fused multiply-add instructions (FMA3: Intel since Haswell, AMD since
#: Piledriver), apart from the chain above: without them LLVM turns each lane
#: of an ``llvm.fma`` into a call of libm's ``fmaf``.
HAVE_FMA = _FOUND["fma"]
