"""How a long-lived worker process keeps its heap from growing: glibc's allocator, tuned once at start-up.

Two defaults of glibc's ``malloc`` make a worker's resident set grow run after run with nothing live to show for it
(measured in ``benchmarks/bench_worker_memory.py``: 707 MB after three 11 s executions, 573 MB tuned):

- the mmap threshold adapts upwards (to 32 MB) each time a large block is freed, so the rollouts', plans' and
  telemetry chunks' arrays of later runs come from the heap, which keeps what it was given;
- every thread that allocates (the execution's, Zenoh's callbacks) gets an arena of its own, each keeping its high
  water mark.

:func:`bound_heap` fixes the threshold at 128 kB (blocks above it are mapped and unmapped on their own, returned to
the system when freed) and allows two arenas; :func:`trim_heap`, after each job, gives the free pages inside the
heaps back. Not glibc (musl, macOS): nothing to tune, nothing done.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
from typing import Any

log = logging.getLogger(__name__)

MMAP_THRESHOLD_BYTES = 128 * 1024
"""Blocks at least this large are mapped on their own (glibc's initial threshold, kept from adapting)."""
ARENAS = 2
"""Heaps threads allocate from (glibc's default is 8 per core)."""
_M_MMAP_THRESHOLD, _M_ARENA_MAX = -3, -8  # glibc's <malloc.h> parameter numbers


def _libc_function(name: str) -> Any:
    """glibc's function ``name``, or None (no C library found, or one without it)."""
    try:
        return getattr(ctypes.CDLL(ctypes.util.find_library("c")), name)
    except (OSError, AttributeError, TypeError):
        return None


def bound_heap() -> bool:
    """Tune this process's allocator as the module docstring says (call before threads start); returns whether it
    could (glibc's ``mallopt`` found and accepting both)."""
    mallopt = _libc_function("mallopt")
    if mallopt is None:
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    done = mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES) == 1 and mallopt(_M_ARENA_MAX, ARENAS) == 1
    if not done:
        log.warning("mallopt refused the heap settings: the worker's memory may grow run after run")
    return done


def trim_heap() -> bool:
    """Give the free memory of the heaps back to the system (glibc's ``malloc_trim(0)``: the free pages anywhere in
    them, not only at the top), after a job whose arrays are gone; returns whether any was released. A few ms."""
    malloc_trim = _libc_function("malloc_trim")
    if malloc_trim is None:
        return False
    malloc_trim.argtypes, malloc_trim.restype = [ctypes.c_size_t], ctypes.c_int
    return malloc_trim(0) == 1
