"""Compiling the hot loops with numba: one place for its options and its disk cache."""

from __future__ import annotations

import warnings

from numba import njit

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
