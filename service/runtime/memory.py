"""Process memory settings for numpy-heavy work, and the garbage collector's view of start-up
and of the long-lived objects.

An exact set allocates many numpy temporaries of 0.1-2 MB. glibc serves blocks above its mmap
threshold with fresh ``mmap`` calls and gives freed heap tops back to the kernel, so every such
temporary costs page faults on first touch: in this VM that made some array operations 3-4x
slower than on warm memory. :func:`keep_freed_memory` raises both thresholds so that freed blocks
are reused instead.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import logging

log = logging.getLogger("frt.memory")

_M_TRIM_THRESHOLD = -1
_M_TOP_PAD = -2
_M_MMAP_THRESHOLD = -3

#: Blocks up to this size come from the heap (glibc's cap for the mmap threshold is 32 MiB on
#: 64-bit machines; larger values are refused).
MMAP_THRESHOLD_BYTES = 32 << 20
#: Free memory kept at the top of the heap before it is returned to the kernel.
TRIM_THRESHOLD_BYTES = 256 << 20
#: Extra memory asked for whenever the heap grows.
TOP_PAD_BYTES = 16 << 20


def keep_freed_memory() -> bool:
    """Tune glibc's allocator of this process (see the module docstring). Returns whether it was
    applied; False where the C library is not glibc (nothing changes then)."""
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    applied = all(
        mallopt(option, value) == 1
        for option, value in (
            (_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES),
            (_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES),
            (_M_TOP_PAD, TOP_PAD_BYTES),
        )
    )
    if not applied:
        log.warning("malloc thresholds not applied")
    return applied


#: Collections of the middle generation between two full collections (CPython's default: 10).
GEN1_COLLECTIONS_PER_FULL = 100


def freeze_start_up_objects() -> None:
    """Move every object alive now (modules, schemas, the model, ...) out of the garbage
    collector's reach: a full collection would traverse them all, a pause in the middle of a
    request; after this only objects made later are traversed. Then make full collections rarer
    (:data:`GEN1_COLLECTIONS_PER_FULL`): a scene's long-lived objects (its agents' states, sets
    and audited versions) are traversed by every full collection, a pause of the event loop that
    grows with them and came several times a second at 10 Hz, while almost none of them ends
    as cyclic garbage (reference counts free them); the young generations are collected as
    before."""
    gc.collect()
    gc.freeze()
    young, middle, _ = gc.get_threshold()
    gc.set_threshold(young, middle, GEN1_COLLECTIONS_PER_FULL)
