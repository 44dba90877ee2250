"""scripts/profile_load.py sorts py-spy's samples into the parts of the work it reports."""

from __future__ import annotations

from pathlib import Path

import pytest

from scripts.profile_load import breakdown, tube_lines

SERVER = 'process 10:"uvicorn service.api.app:app"'
WORKER = 'process 11:"python -c from multiprocessing.spawn import spawn_main"'
LOOP = "thread (1): MainThread;<module> (uvicorn:6);Server.run (uvicorn/server.py:86);Runner.run (asyncio/runners.py:118)"
READER = "thread (2): pipe-pool-reader;Thread.run (threading.py:982);PipePool._read (service/runtime/pipe_pool.py:160)"
SERVE = "thread (3): MainThread;_serve (service/runtime/pipe_pool.py:48);timed (service/runtime/scheduler.py:511);ExactTask.__call__ (service/runtime/exact_worker.py:85)"


def test_samples_are_sorted_into_parts_by_their_stacks(tmp_path: Path) -> None:
    for_checks, whole = tube_lines()
    assert len(for_checks) == 1 and len(whole) == 1  # the engine draws both, once each
    (check_line,), (whole_line,) = for_checks, whole
    exact = "FRTEngine.exact (reach/engine.py:{});FieldTubeSet.tube (reach/field_tube.py:230)"
    lines = [
        f"{SERVER};{WORKER};{SERVE};{exact.format(check_line)} 300",
        f"{SERVER};{WORKER};{SERVE};{exact.format(whole_line)} 20",
        f"{SERVER};{WORKER};{SERVE};FRTEngine.exact (reach/engine.py:215);FRTEngine._grid (reach/engine.py:260) 40",
        f"{SERVER};{WORKER};thread (3): MainThread;_serve (service/runtime/pipe_pool.py:60);dumps (pickle:1) 10",
        f"{SERVER};{LOOP};observe (service/flows/agents.py:140) 50",
        f"{SERVER};{LOOP};answer_states (service/flows/checks.py:120) 30",
        f"{SERVER};{READER} 15",
    ]
    raw = tmp_path / "samples.txt"
    raw.write_text("\n".join(lines) + "\n")
    result = breakdown(raw, rate=100.0)
    workers = result["parts"]["workers"]
    assert workers["tubes for time-indexed checks"] == pytest.approx(3.0)
    assert workers["whole-horizon tube"] == pytest.approx(0.2)
    assert workers["exact set: lattice and polygon fields"] == pytest.approx(0.4)
    assert workers["sending the set back"] == pytest.approx(0.1)
    loop = result["parts"]["server event loop"]
    assert loop == pytest.approx({"observations": 0.5, "collision checks: answering": 0.3})
    other = result["parts"]["server other threads"]
    assert other == pytest.approx({"pipe pool reader (reading sets)": 0.15})
    assert result["processes"] == {"workers": 1, "server": 1}
