"""An LLVM instruction numba does not expose, for the search's hot loops."""

from __future__ import annotations

from llvmlite import ir
from numba import types
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
