"""Lane blocks: several rows computed at once in the CPU's SIMD lanes, from scalar source.

The stepping kernels advance :data:`LANES` rows at a time as a *lane block*: each quantity of
the block is an array whose last axis is the lane (``x[i, lane]``), and the per-row code runs in
an innermost ``for lane in range(lanes)`` loop over views of one lane (``x[:, lane]``). LLVM
vectorises such a loop across the lanes when

- its width is a compile-time constant, and its arrays' shapes and strides too, and LLVM can
  see that they do not overlap: the arrays come from :func:`stack_array`, fixed-size buffers on
  the stack of the compiled function, one object each;
- the body is straight-line code: no inner loops, no calls (branches become selects).

IEEE addition, multiplication, division and square root give the same bits in each lane as in
scalar code, so with no fastmath flags (``bogie_env.integrate.FASTMATH``: no FMA contraction, no
reassociation) a row's result does not depend on whether it ran in a lane block or alone.
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir as llvm_ir
from numba import types
from numba.extending import intrinsic

#: Rows per lane block: 8 float64 fill a 512-bit register (AVX-512); on narrower hardware LLVM
#: splits the block into several registers, with the same results.
LANES = 8


@intrinsic(prefer_literal=True)
def stack_array(typingctx, shape):
    """A C-contiguous float64 array of a compile-time ``shape`` (a tuple of integer literals) in
    the stack frame of the compiled function that calls it: uninitialised, no allocation, no
    reference counting (usable with ``_nrt=False``). It lives until that function returns."""
    if not isinstance(shape, types.BaseTuple) or not all(isinstance(d, types.IntegerLiteral) for d in shape):
        return None
    dims = [d.literal_value for d in shape]
    array_type = types.Array(types.float64, len(dims), "C")

    def codegen(context, builder, signature, args):
        count = int(np.prod(dims))
        with builder.goto_entry_block():  # one buffer per call of the function, not per loop trip
            block = builder.alloca(llvm_ir.ArrayType(llvm_ir.DoubleType(), count))
            block.align = 64
        array = context.make_array(array_type)(context, builder)
        intp = context.get_value_type(types.intp)
        strides = [8 * int(np.prod(dims[k + 1 :])) for k in range(len(dims))]
        context.populate_array(array, data=builder.bitcast(block, llvm_ir.DoubleType().as_pointer()),
                               shape=[intp(d) for d in dims], strides=[intp(s) for s in strides], itemsize=intp(8),
                               meminfo=None)  # fmt: skip
        return array._getvalue()

    return array_type(shape), codegen
