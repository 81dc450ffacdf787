"""Handing freed memory back to the system."""

from __future__ import annotations

import sys


def release_freed_memory() -> None:
    """Return the C heap's free pages to the system (glibc's ``malloc_trim``); a no-op where
    there is no such call.

    glibc keeps freed heap pages resident unless they lie at the top of its heap. After a
    calibration at thousands of configurations, tens of MB freed by its Jacobians stay resident
    that way, and the report's figures (matplotlib and its libraries) would add to them and set
    the command's peak memory."""
    if not sys.platform.startswith("linux"):
        return
    try:
        import ctypes  # here: a Python built without ctypes still writes its reports

        trim = ctypes.CDLL(None).malloc_trim  # the process's own C library
    except (ImportError, OSError, AttributeError):  # musl and others have no malloc_trim
        return
    trim.argtypes, trim.restype = [ctypes.c_size_t], ctypes.c_int
    trim(0)
