"""Allocator tuning for generation and export: glibc's ``mallopt``, once per process (``PHYSYNTH_MALLOPT=0``: not).

A trace allocates and frees dozens of arrays of 0.1-1 MB (41,560 IMU samples x 3 x 8 bytes is 1 MB).
glibc serves blocks above its mmap threshold (128 kB, raised dynamically up to 32 MB as mmapped blocks
are freed) with a fresh ``mmap`` each time, and gives the top of the heap back to the system above its
trim threshold: every such array is then faulted in page by page again (~750 minor page faults per
default trace, about 15 % of its CPU time). Setting ``M_MMAP_THRESHOLD`` to 4 MB and
``M_TRIM_THRESHOLD`` to 32 MB keeps those blocks on the heap and reuses them (about one page fault
per trace). The values generated do not change.

This is a **process-wide** setting: every later ``malloc`` of the process (NumPy, pyarrow, any other
library) sees it. The price is memory: up to 32 MB of freed heap may stay mapped instead of going back
to the system, and blocks up to 4 MB come from the heap, where they can fragment it. It is applied
the first time :func:`physynth.generate.compile_scenario` runs (every generation path goes through
it) or an export part starts (:func:`physynth.io.export.parts.export_part`: Dask's nanny starts its
workers with ``MALLOC_TRIM_THRESHOLD_=65536``, which made a worker writing ROS 2 bags fault its freed
heap in again, 2,800 page faults per trace), only on Linux with glibc (a no-op elsewhere, e.g. macOS,
Windows, musl), and never when the environment variable ``PHYSYNTH_MALLOPT`` is ``0`` (or ``false``, ``no``,
``off``) at that moment.
"""

from __future__ import annotations

import os
import sys

ENV_VAR = "PHYSYNTH_MALLOPT"
M_TRIM_THRESHOLD = -1  # glibc <malloc.h> parameter numbers
M_MMAP_THRESHOLD = -3
TRIM_THRESHOLD_BYTES = 32 * 1024 * 1024
MMAP_THRESHOLD_BYTES = 4 * 1024 * 1024

_state: dict[str, bool | None] = {"applied": None}  # None: not tried yet in this process


def opted_out() -> bool:
    """True when ``PHYSYNTH_MALLOPT`` asks not to touch the allocator."""
    return os.environ.get(ENV_VAR, "").strip().lower() in {"0", "false", "no", "off"}


def is_glibc() -> bool:
    """True on Linux with glibc (the only place where the tuning applies)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        return bool(os.confstr("CS_GNU_LIBC_VERSION"))  # None or an error outside glibc
    except (AttributeError, ValueError, OSError):
        return False


def _load_mallopt():
    """glibc's ``int mallopt(int, int)`` through ctypes, or None."""
    import ctypes

    try:
        fn = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return None
    fn.argtypes = (ctypes.c_int, ctypes.c_int)
    fn.restype = ctypes.c_int
    return fn


def tune_allocator() -> bool:
    """Set glibc's mmap and trim thresholds once per process; True when they are set (now or before).

    Does nothing (and returns False) when ``PHYSYNTH_MALLOPT=0``, off glibc Linux, or when ``mallopt``
    cannot be found; a later call does not try again.
    """
    if _state["applied"] is not None:
        return bool(_state["applied"])
    applied = False
    if not opted_out() and is_glibc():
        mallopt = _load_mallopt()
        if mallopt is not None:
            applied = bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) & bool(
                mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))
    _state["applied"] = applied
    return applied
