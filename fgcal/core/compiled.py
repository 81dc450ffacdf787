"""Compiling the hot loops with numba: one place for its options and its disk cache."""

from __future__ import annotations

import warnings

from numba import njit
from numba.core import cgutils, types
from numba.core.imputils import impl_ret_borrowed
from numba.extending import intrinsic
from numba.np.arrayobj import make_array, populate_array

# fastmath stays off: reordered arithmetic would move the results further from NumPy's than
# the rounding of a different summation order (a few ulp), which the tests bound.
_OPTIONS = {"nogil": True, "error_model": "numpy"}


def compiled(function=None, *, inline: bool = False):
    """``function`` compiled by numba, its machine code cached on disk; where numba finds no
    writable cache folder (a read-only install, a user without a home) it raises on caching,
    and each process compiles instead (a few seconds at its first evaluation).

    ``inline``: a function the other kernels call, compiled into each of them. A call between
    compiled functions otherwise costs about as much as a few of its loops (10-15 % of the
    Jacobian of every parameter, 0.6 us of a single configuration's FK)."""
    options = {**_OPTIONS, "inline": "always"} if inline else _OPTIONS

    def compile(function):
        try:
            return njit(cache=True, **options)(function)
        except RuntimeError as exc:
            if "no locator available" not in str(exc):
                raise
            warnings.warn(  # once: the same message from the same line
                "fgcal: numba finds no writable folder to cache the compiled kernels in, so each process "
                "compiles them (a few seconds); set NUMBA_CACHE_DIR to a writable folder to keep them",
                RuntimeWarning,
                stacklevel=1,
            )
            return njit(cache=False, **options)(function)

    return compile if function is None else compile(function)


@intrinsic
def view(typingctx, array, shape):
    """``array`` (a C-contiguous 1-D array) as a C-ordered array of ``shape`` (a tuple of ints),
    a view sharing its memory: ``array.reshape(shape)`` without its checks, which cost about
    20 ns at every call (a single configuration's FK and Jacobian took sixteen). The caller
    guarantees ``prod(shape) <= len(array)``; nothing checks it."""
    if not (isinstance(array, types.Array) and array.ndim == 1 and array.layout == "C"):
        return None
    if not (isinstance(shape, types.BaseTuple) and all(isinstance(size, types.Integer) for size in shape)):
        return None
    result = array.copy(ndim=len(shape), layout="C")

    def codegen(context, builder, signature, args):
        source = make_array(signature.args[0])(context, builder, args[0])
        sizes = zip(cgutils.unpack_tuple(builder, args[1]), signature.args[1], strict=True)
        dims = [context.cast(builder, size, kind, types.intp) for size, kind in sizes]
        strides, stride = [], source.itemsize
        for dim in reversed(dims):
            strides.append(stride)
            stride = builder.mul(stride, dim)
        out = make_array(signature.return_type)(context, builder)
        populate_array(
            out, data=source.data, shape=dims, strides=strides[::-1], itemsize=source.itemsize,
            meminfo=source.meminfo, parent=source.parent,
        )  # fmt: skip
        return impl_ret_borrowed(context, builder, signature.return_type, out._getvalue())

    return result(array, shape), codegen
