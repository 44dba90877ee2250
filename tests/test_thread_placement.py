"""Helper threads run off the CPU of the thread that hands them work."""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

import pytest

from reach import thread_placement
from reach.batch import run_on_threads

ALLOWED = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
needs_two_cpus = pytest.mark.skipif(
    len(ALLOWED) < 2 or thread_placement.current_cpu() < 0,
    reason="needs two CPUs and sched_getcpu",
)


@contextmanager
def calling_thread_on(cpu: int) -> Iterator[None]:
    """The calling thread pinned to ``cpu`` while the block runs."""
    before = os.sched_getaffinity(0)
    os.sched_setaffinity(0, {cpu})
    try:
        yield
    finally:
        os.sched_setaffinity(0, before)


def test_the_current_cpu_is_one_the_thread_may_use() -> None:
    cpu = thread_placement.current_cpu()
    assert cpu == -1 or cpu in os.sched_getaffinity(0)


@needs_two_cpus
@pytest.mark.parametrize("caller_cpu", [ALLOWED[0], ALLOWED[-1]] if len(ALLOWED) > 1 else [0])
def test_kernel_helpers_run_on_other_cpus_than_the_caller(caller_cpu: int) -> None:
    """Every call a helper thread makes runs on a CPU other than the caller's, and the helper
    may use every other CPU."""
    seen: list[tuple[str, int]] = []

    def call() -> None:
        time.sleep(0.001)  # without the GIL, as the kernels run: both threads take calls
        seen.append((threading.current_thread().name, thread_placement.current_cpu()))

    run_on_threads([call] * 4, 2)  # the helper started with every CPU the process may use
    seen.clear()
    with calling_thread_on(caller_cpu):
        run_on_threads([call] * 40, 2)
        helpers = [t for t in threading.enumerate() if t.name == "frt-kernel"]
        masks = [os.sched_getaffinity(t.native_id) for t in helpers]  # type: ignore[arg-type]
    on_helpers = [cpu for name, cpu in seen if name == "frt-kernel"]
    assert on_helpers, "no call ran on a helper thread"
    assert caller_cpu not in on_helpers
    assert all(mask == set(ALLOWED) - {caller_cpu} for mask in masks)


@needs_two_cpus
def test_a_helper_keeps_its_cpus_when_the_caller_s_cpu_is_unknown_or_its_only_one() -> None:
    ready, stop = threading.Event(), threading.Event()
    ids: list[int] = []

    def helper() -> None:
        ids.append(threading.get_native_id())
        ready.set()
        stop.wait(10)

    thread = threading.Thread(target=helper)
    thread.start()
    ready.wait(10)
    (native_id,) = ids
    try:
        thread_placement.register(native_id)
        thread_placement.keep_helpers_off(ALLOWED[0])
        assert os.sched_getaffinity(native_id) == set(ALLOWED) - {ALLOWED[0]}
        thread_placement.keep_helpers_off(-1)
        assert os.sched_getaffinity(native_id) == set(ALLOWED)
        os.sched_setaffinity(native_id, {ALLOWED[1]})
        thread_placement.register(native_id)  # its CPUs now: ALLOWED[1] alone
        thread_placement.keep_helpers_off(ALLOWED[1])
        assert os.sched_getaffinity(native_id) == {ALLOWED[1]}
        os.sched_setaffinity(native_id, ALLOWED)
        thread_placement.register(native_id)
    finally:
        stop.set()
        thread.join()
    # join() returns when Python is done with the thread, which the OS may still be ending.
    deadline = time.monotonic() + 10.0
    while os.path.exists(f"/proc/self/task/{native_id}") and time.monotonic() < deadline:
        time.sleep(0.001)
    thread_placement.keep_helpers_off(ALLOWED[0])  # the ended thread is forgotten, no error
    assert native_id not in thread_placement._helpers
