"""LLVM instructions numba does not expose, for the search's hot loops."""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic


@intrinsic
def pick(typingctx, cond, if_true, if_false):
    """`if_true if cond else if_false` for integers as one LLVM `select` (a cmov),
    where numba's conditional expression becomes a branch — which mispredicts about
    half the time when it picks the lower of two random costs."""
    if not (isinstance(if_true, types.Integer) and if_true == if_false):
        return None

    def codegen(context, builder, signature, args):
        c = args[0]
        if c.type != ir.IntType(1):
            c = builder.icmp_unsigned("!=", c, ir.Constant(c.type, 0))
        return builder.select(c, args[1], args[2])

    return if_true(cond, if_true, if_false), codegen


def _float_select(predicate: str):
    def select(typingctx, a, b):
        if not (isinstance(a, types.Float) and a == b):
            return None

        def codegen(context, builder, signature, args):
            return builder.select(builder.fcmp_ordered(predicate, args[0], args[1]), args[0], args[1])

        return a(a, b), codegen

    return select


# `a if a < b else b` (fmin) and `a if a > b else b` (fmax) for floats of one type: one
# minss / maxss, no branch (numba's min() and max() add NaN checks; the search's values
# are never NaN).
fmin = intrinsic(_float_select("<"))
fmax = intrinsic(_float_select(">"))


@intrinsic
def tag(typingctx, value, keep, label):
    """A float32 ≥ 0 with its low mantissa bits replaced by a small label:
    bits(value) & keep | label. For non-negative floats the bit pattern orders like
    the value, so the minimum of tagged values carries its label along, ties going to
    the lower label; the value moves by less than 2^k ulps (k the label bits)."""
    if not (value == types.float32 and isinstance(keep, types.Integer) and isinstance(label, types.Integer)):
        return None

    def codegen(context, builder, signature, args):
        i32 = ir.IntType(32)

        def as_i32(v):
            return v if v.type.width == 32 else builder.trunc(v, i32) if v.type.width > 32 else builder.zext(v, i32)

        bits = builder.bitcast(args[0], i32)
        out = builder.or_(builder.and_(bits, as_i32(args[1])), as_i32(args[2]))
        return builder.bitcast(out, ir.FloatType())

    return types.float32(value, keep, label), codegen


@intrinsic
def prefetch(typingctx, array, index):
    """Ask the CPU to start loading row `index` of a C-contiguous array (llvm.prefetch,
    read, keep in all cache levels): scattered row reads that the out-of-order window
    cannot reach in time otherwise. Only a hint: no fault, no effect on results."""
    if not (isinstance(array, types.Array) and array.layout == "C" and isinstance(index, types.Integer)):
        return None

    def codegen(context, builder, signature, args):
        array_type, index_type = signature.args
        ary = context.make_array(array_type)(context, builder, args[0])
        row = context.cast(builder, args[1], index_type, types.intp)
        indices = [row] + [context.get_constant(types.intp, 0)] * (array_type.ndim - 1)
        ptr = cgutils.get_item_pointer(context, builder, array_type, ary, indices, wraparound=False, boundscheck=False)
        i8p = ir.IntType(8).as_pointer()
        i32 = ir.IntType(32)
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32]),
                                            "llvm.prefetch.p0i8")  # fmt: skip
        builder.call(fn, [builder.bitcast(ptr, i8p), ir.Constant(i32, 0), ir.Constant(i32, 3), ir.Constant(i32, 1)])
        return context.get_dummy_value()

    return types.none(array, index), codegen
