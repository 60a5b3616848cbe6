"""What the Viterbi kernels are built with: LLVM instructions numba does not expose
(a branch-free select, min / max, fused multiply-add, prefetch, float32 tagging and
eight-wide candidate keeping for the float32 pass), and `compile_kernel`, which
compiles each kernel threaded and serial.

`keep_two_placed8` computes the float32 pass's placed total (W_A·C_A + W_P·C_P +
W_O·C_O from a source's relative row) eight edges at a time in LLVM IR: it must agree
bit for bit with `costs._placed_total32` (see `costs` for every place a term is
computed)."""

from __future__ import annotations

from types import FunctionType

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

_I32, _I64, _F32 = ir.IntType(32), ir.IntType(64), ir.FloatType()
_V8F, _V8I = ir.VectorType(_F32, 8), ir.VectorType(_I32, 8)


@intrinsic
def pick(typingctx, cond, if_true, if_false):
    """`if_true if cond else if_false` for integers or floats as one LLVM `select` (a
    cmov, or a blend in a vectorised loop), where numba's conditional expression
    becomes a branch — which mispredicts about half the time when it picks the lower
    of two random costs, and keeps a loop from being vectorised."""
    if not (isinstance(if_true, (types.Integer, types.Float)) and if_true == if_false):
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
        def as_i32(v):
            return v if v.type.width == 32 else builder.trunc(v, _I32) if v.type.width > 32 else builder.zext(v, _I32)

        bits = builder.bitcast(args[0], _I32)
        out = builder.or_(builder.and_(bits, as_i32(args[1])), as_i32(args[2]))
        return builder.bitcast(out, _F32)

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
        fn = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(ir.VoidType(), [i8p, _I32, _I32, _I32]), "llvm.prefetch.p0i8"
        )
        builder.call(fn, [builder.bitcast(ptr, i8p), ir.Constant(_I32, 0), ir.Constant(_I32, 3), ir.Constant(_I32, 1)])
        return context.get_dummy_value()

    return types.none(array, index), codegen


def _gathers(context) -> bool:
    """Whether the code numba makes may use AVX2's gather instructions (the target's
    features, as numba sets them: the host's unless NUMBA_CPU_FEATURES says otherwise)."""
    return "+avx2" in str(getattr(context.codegen(), "_tm_features", "")).split(",")


class _Lanes:
    """Eight-lane LLVM IR for the intrinsics below: array data pointers, unaligned
    vector loads and stores at an element index, broadcasts, shuffles."""

    def __init__(self, context, builder, signature, args):
        self.context, self.builder = context, builder
        self.types, self.args = signature.args, args

    def data(self, k):
        """Argument k's (an array's) data pointer."""
        return self.context.make_array(self.types[k])(self.context, self.builder, self.args[k]).data

    def index(self, k):
        """Argument k (an integer) as intp."""
        return self.context.cast(self.builder, self.args[k], self.types[k], types.intp)

    def load(self, ptr, index, vector_type):
        b = self.builder
        return b.load(b.bitcast(b.gep(ptr, [index]), vector_type.as_pointer()), align=4)

    def store(self, value, ptr, index):
        b = self.builder
        b.store(value, b.bitcast(b.gep(ptr, [index]), value.type.as_pointer()), align=4)

    def splat(self, value, vector_type=_V8F):
        b = self.builder
        one = b.insert_element(ir.Constant(vector_type, ir.Undefined), value, ir.Constant(_I32, 0))
        return b.shuffle_vector(one, ir.Constant(vector_type, ir.Undefined), ir.Constant(_V8I, [0] * 8))

    def shuffle(self, a, b, mask):
        return self.builder.shuffle_vector(a, b, ir.Constant(ir.VectorType(_I32, len(mask)), mask))

    def call(self, name, *values):
        fn = cgutils.get_or_insert_function(self.builder.module, ir.FunctionType(_V8F, [_V8F] * len(values)), name)
        return self.builder.call(fn, list(values))

    def keep_two(self, t, keep, labels, i, best, second, p):
        """Tag the totals t with the labels at i (argument numbers keep, labels), then
        `dense._keep_two` them into the best and second arrays (argument numbers) at p."""
        b = self.builder
        keep_ = self.context.cast(b, self.args[keep], self.types[keep], types.uint32)
        bits = ir.IntType(self.types[labels].dtype.bitwidth)
        label = b.zext(self.load(self.data(labels), i, ir.VectorType(bits, 8)), _V8I)
        t = b.bitcast(b.or_(b.and_(b.bitcast(t, _V8I), self.splat(keep_, _V8I)), label), _V8F)
        best_d, second_d = self.data(best), self.data(second)
        lowest, runner_up = self.load(best_d, p, _V8F), self.load(second_d, p, _V8F)
        higher = b.select(b.fcmp_ordered(">", t, lowest), t, lowest)
        self.store(b.select(b.fcmp_ordered("<", runner_up, higher), runner_up, higher), second_d, p)
        self.store(b.select(b.fcmp_ordered("<", t, lowest), t, lowest), best_d, p)


def _vectors(arrays, dtype) -> bool:
    return all(isinstance(a, types.Array) and a.layout == "C" and a.ndim == 1 and a.dtype == dtype for a in arrays)


def _labels(labels) -> bool:
    return isinstance(labels, types.Array) and labels.layout == "C" and labels.dtype in (types.uint8, types.uint16)


@intrinsic
def keep_two_gathered8(typingctx, best, second, p, costs, src, i, extra, weight, keep, labels):
    """Eight candidates at once for `dense._keep_two` (viterbi.py) at positions p … p+7:
    t = tag(costs[src[i + k]] + weight · extra[p + k], keep, labels[i + k]) for k < 8 (a
    multiply, then an add: no fused multiply-add), then
    second = fmin(second, fmax(t, best)) and best = fmin(t, best) lane by lane — the
    scalar loop's values, bit for bit. The eight scattered costs come in one gather
    (AVX2 `vgatherdps` where the target has it, else eight loads), where the scalar
    loop spends a load, a tag and three min/max instructions on each. best, second,
    costs, extra (…,) float32, src (…,) uint32 and labels (…,) unsigned (8 or 16
    bits), C-contiguous; weight float32; p, i unsigned; src's entries < 2³¹."""
    if not (
        _vectors((best, second, costs, extra), types.float32)
        and _vectors((src,), types.uint32)
        and _labels(labels)
        and weight == types.float32
        and all(isinstance(x, types.Integer) for x in (p, i, keep))
    ):
        return None

    def codegen(context, builder, signature, args):
        v = _Lanes(context, builder, signature, args)
        p_, i_ = v.index(2), v.index(5)
        index = v.load(v.data(4), i_, _V8I)
        costs_d = v.data(3)
        if _gathers(context):
            i8 = ir.IntType(8)
            gather = cgutils.get_or_insert_function(
                builder.module,
                ir.FunctionType(_V8F, [_V8F, i8.as_pointer(), _V8I, _V8F, i8]),
                "llvm.x86.avx2.gather.d.ps.256",
            )
            every_lane = builder.bitcast(ir.Constant(_V8I, [-1] * 8), _V8F)
            cost = builder.call(
                gather,
                [
                    ir.Constant(_V8F, [0.0] * 8),
                    builder.bitcast(costs_d, i8.as_pointer()),
                    index,
                    every_lane,
                    ir.Constant(i8, 4),
                ],
            )
        else:
            cost = ir.Constant(_V8F, ir.Undefined)
            for k in range(8):
                lane = builder.zext(builder.extract_element(index, ir.Constant(_I32, k)), _I64)
                cost = builder.insert_element(cost, builder.load(builder.gep(costs_d, [lane])), ir.Constant(_I32, k))
        t = builder.fadd(cost, builder.fmul(v.splat(args[7]), v.load(v.data(6), p_, _V8F)))
        v.keep_two(t, 8, 9, i_, 0, 1, p_)
        return context.get_dummy_value()

    return types.none(best, second, p, costs, src, i, extra, weight, keep, labels), codegen


@intrinsic
def keep_two_placed8(typingctx, best, second, p, rel, src, i, offset, turn, extra, w_acc, w_pos, w_head, keep, labels):
    """`keep_two_gathered8` for placed searches: eight candidates at positions p … p+7
    from relative rows rel (R, 4) float32 [qx, qz, rh, cost] of the sources src[i + k]
    (uint32): t = cost + w_acc · extra[p + k] + w_pos · |q + offset[i + k]|
    + w_head · |wrap(rh + turn[i + k])|, tagged with labels[i + k] — `costs._place_terms`'
    float32 operations in the same order, so the scalar loop's values bit for bit.
    The eight rows come in eight 16-byte loads, transposed into four vectors.
    offset (…, 2) and turn, extra (…,) float32; C-contiguous arrays."""
    if not (
        _vectors((best, second, turn, extra), types.float32)
        and _vectors((src,), types.uint32)
        and _labels(labels)
        and w_acc == w_pos == w_head == types.float32
        and all(
            isinstance(a, types.Array) and a.layout == "C" and a.ndim == 2 and a.dtype == types.float32
            for a in (rel, offset)
        )
        and all(isinstance(x, types.Integer) for x in (p, i, keep))
    ):
        return None

    def codegen(context, builder, signature, args):
        v = _Lanes(context, builder, signature, args)
        p_, i_ = v.index(2), v.index(5)
        index, rel_d = v.load(v.data(4), i_, _V8I), v.data(3)
        rows = []
        for k in range(8):
            row = builder.zext(builder.extract_element(index, ir.Constant(_I32, k)), _I64)
            rows.append(v.load(rel_d, builder.mul(row, ir.Constant(_I64, 4)), ir.VectorType(_F32, 4)))
        # rows k and k+4 side by side, then a 4 × 4 transpose within each 128-bit half
        r04, r15, r26, r37 = (v.shuffle(rows[k], rows[k + 4], list(range(8))) for k in range(4))
        low, high = [0, 8, 1, 9, 4, 12, 5, 13], [2, 10, 3, 11, 6, 14, 7, 15]
        lo01, hi01, lo23, hi23 = (
            v.shuffle(r04, r15, low),
            v.shuffle(r04, r15, high),
            v.shuffle(r26, r37, low),
            v.shuffle(r26, r37, high),
        )
        pairs_a, pairs_b = [0, 1, 8, 9, 4, 5, 12, 13], [2, 3, 10, 11, 6, 7, 14, 15]
        qx, qz = v.shuffle(lo01, lo23, pairs_a), v.shuffle(lo01, lo23, pairs_b)
        rh, cost = v.shuffle(hi01, hi23, pairs_a), v.shuffle(hi01, hi23, pairs_b)
        offsets = v.load(v.data(6), builder.mul(i_, ir.Constant(_I64, 2)), ir.VectorType(_F32, 16))
        dx = builder.fadd(qx, v.shuffle(offsets, offsets, [0, 2, 4, 6, 8, 10, 12, 14]))
        dz = builder.fadd(qz, v.shuffle(offsets, offsets, [1, 3, 5, 7, 9, 11, 13, 15]))
        pos = v.call("llvm.sqrt.v8f32", builder.fadd(builder.fmul(dx, dx), builder.fmul(dz, dz)))
        a = builder.fadd(rh, v.load(v.data(7), i_, _V8F))
        pi, two_pi, inv_two_pi = (
            v.splat(ir.Constant(_F32, float(np.float32(x)))) for x in (np.pi, 2 * np.pi, 0.5 / np.pi)
        )
        turns = v.call("llvm.floor.v8f32", builder.fmul(builder.fadd(a, pi), inv_two_pi))
        head = v.call("llvm.fabs.v8f32", builder.fsub(a, builder.fmul(two_pi, turns)))
        t = builder.fadd(cost, builder.fmul(v.splat(args[9]), v.load(v.data(8), p_, _V8F)))
        t = builder.fadd(t, builder.fmul(v.splat(args[10]), pos))
        t = builder.fadd(t, builder.fmul(v.splat(args[11]), head))
        v.keep_two(t, 12, 13, i_, 0, 1, p_)
        return context.get_dummy_value()

    return types.none(best, second, p, rel, src, i, offset, turn, extra, w_acc, w_pos, w_head, keep, labels), codegen


@intrinsic
def fma(typingctx, a, b, c):
    """a · b + c rounded once (llvm.fma): the same value on every target, where whether
    numba's fastmath fuses a multiply and an add depends on how LLVM schedules them."""
    if not (isinstance(a, types.Float) and a == b == c):
        return None

    def codegen(context, builder, signature, args):
        t = args[0].type
        name = "llvm.fma.f32" if t == _F32 else "llvm.fma.f64"
        return builder.call(cgutils.get_or_insert_function(builder.module, ir.FunctionType(t, [t, t, t]), name), args)

    return a(a, b, c), codegen


def compile_kernel(fn, parallel: bool):
    """fn compiled threaded (its prange loops spread over numba's threads) or serial.
    Each kernel is compiled both ways: threaded for one search using the whole machine
    (batch), serial for many searches side by side (a server's streams), where threads
    would only fight. The serial one is compiled from a copy of fn named …_serial:
    numba's disk cache files a function under its name and line and tells entries
    apart by signature, bytecode and closure, not by compile flags, so the two would
    load each other's machine code — whichever was cached first served both (seen:
    "serial" streams running threaded kernels)."""
    if not parallel:
        qualname = fn.__qualname__ + "_serial"
        fn = FunctionType(fn.__code__, fn.__globals__, fn.__name__ + "_serial", fn.__defaults__, fn.__closure__)
        fn.__qualname__ = qualname
    return numba.njit(cache=True, nogil=True, parallel=parallel)(fn)
