"""Helper threads kept off the CPU of the thread that hands them work.

Linux wakes a sleeping thread on the waker's CPU when that looks cheaper than waking an idle one
(wake-affine placement), and on a machine left idle between requests the load balancer moves it
to the idle CPU only milliseconds later. Helper threads woken for a few milliseconds of compiled
work then share the caller's CPU, each waiting for the other, while the other CPU sleeps. So,
before the caller wakes them, each registered helper's affinity is set to the CPUs it may use
(those it had when registered) but the one the caller runs on; where that leaves none, or the C
library does not say which CPU a thread runs on, the helpers keep the CPUs they have.
"""

from __future__ import annotations

import ctypes
import os
import threading

try:
    _sched_getcpu = ctypes.CDLL(None, use_errno=True).sched_getcpu
    _sched_getcpu.restype = ctypes.c_int
    _sched_getcpu.argtypes = []
except (AttributeError, OSError):  # not glibc/musl on Linux
    _sched_getcpu = None

#: Per registered helper (its native thread id): the CPUs it may use, and those it is set to.
_helpers: dict[int, tuple[frozenset[int], frozenset[int]]] = {}
_lock = threading.Lock()


def current_cpu() -> int:
    """The CPU the calling thread runs on (-1 where the C library does not say)."""
    if _sched_getcpu is None:
        return -1
    return int(_sched_getcpu())


def register(native_id: int) -> None:
    """Place the thread ``native_id`` (``threading.Thread.native_id``) from now on, with the
    CPUs it may use now."""
    try:
        allowed = frozenset(os.sched_getaffinity(native_id))
    except (AttributeError, OSError):
        return
    with _lock:
        _helpers[native_id] = (allowed, allowed)


def keep_helpers_off(cpu: int) -> None:
    """Set every registered helper's affinity to its CPUs but ``cpu`` (all of them if that
    leaves none, or ``cpu`` is -1); a helper already so set is left as it is."""
    with _lock:
        for native_id, (allowed, current) in list(_helpers.items()):
            wanted = allowed - {cpu} or allowed
            if wanted == current:
                continue
            try:
                os.sched_setaffinity(native_id, wanted)
            except OSError:  # the thread has ended, or may not be placed so: left alone
                del _helpers[native_id]
                continue
            _helpers[native_id] = (allowed, wanted)


def keep_helpers_off_caller() -> None:
    """:func:`keep_helpers_off` the calling thread's CPU."""
    keep_helpers_off(current_cpu())


def forget_helpers() -> None:
    """Forget every registered helper (in a forked child, which holds none of the parent's
    threads)."""
    with _lock:
        _helpers.clear()
