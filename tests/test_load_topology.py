"""scripts/load_topology.py's accounting: CPU seconds per process and a server's workers."""

from __future__ import annotations

import os
import subprocess
import sys
import time

from scripts.load_topology import children, cpu_seconds


def test_cpu_seconds_grow_with_work_and_children_are_found() -> None:
    spin = "while True: pass"
    child = subprocess.Popen([sys.executable, "-c", spin])
    try:
        assert child.pid in children(os.getpid())
        assert cpu_seconds(child.pid) < 5.0  # just started
        deadline = time.monotonic() + 30.0  # a busy machine may give it little CPU
        while cpu_seconds(child.pid) < 0.2 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert cpu_seconds(child.pid) >= 0.2
    finally:
        child.kill()
        child.wait(timeout=30)
    assert cpu_seconds(child.pid) == 0.0  # gone: nothing to count
    assert child.pid not in children(os.getpid())
