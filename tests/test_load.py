"""scripts/load.py against the live test server for a few seconds: no errors, no lost updates."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest

from tests.conftest import LiveServer

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parent.parent
SCRIPT = ROOT / "scripts" / "load.py"


def load_module() -> ModuleType:
    spec = importlib.util.spec_from_file_location("frt_load_script", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while the class is built
    spec.loader.exec_module(module)
    return module


def run_load(*args: str, timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, str(SCRIPT), *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def test_a_short_load_run_has_no_errors_and_no_lost_updates(
    live_server: LiveServer, tmp_path: Path
) -> None:
    out = tmp_path / "load.json"
    done = run_load(
        "--url", live_server.url, "--duration", "5", "--planners", "2", "--humans", "4",
        "--obs-hz", "5", "--check-hz", "10", "--out", str(out),
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    summary = json.loads(out.read_text())
    assert summary["ok"] and summary["errors"] == 0
    verification = summary["verification"]
    assert verification["lost_updates"] == 0 and verification["verified"] == 4
    assert verification["answers_off"] == 0
    assert verification["max_beta_diff"] <= 1e-9
    ops = summary["operations"]
    # Throughput depends on the machine's load: ask only for enough traffic to verify the filter.
    assert ops["observe"]["count"] >= 4 * 2  # every human observed at least twice
    assert ops["check"]["count"] >= 2
    assert all(ops[op]["p50_ms"] <= ops[op]["p99_ms"] <= ops[op]["max_ms"] for op in ops)
    assert out.with_suffix(".png").stat().st_size > 10_000
    assert "p99 ms" in done.stdout and "lost or reordered updates: 0" in done.stdout


def test_frames_in_scenes_lose_nothing(live_server: LiveServer, tmp_path: Path) -> None:
    out = tmp_path / "frames.json"
    done = run_load(
        "--url", live_server.url, "--duration", "5", "--planners", "1", "--humans", "5",
        "--scenes", "2", "--frames", "--obs-hz", "5", "--check-hz", "10", "--out", str(out),
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    summary = json.loads(out.read_text())
    assert summary["ok"] and summary["config"]["scenes"] == 2 and summary["config"]["frames"]
    verification = summary["verification"]
    assert verification["lost_updates"] == 0 and verification["verified"] == 5
    assert verification["answers_off"] == 0
    ops = summary["operations"]
    assert "observe" not in ops and ops["frame"]["count"] >= 2 * 2  # each scene twice at least
    assert ops["check"]["count"] >= 2
    # Scenes of 3 and 2 humans: every frame stores a version of each of its scene's humans.
    assert 2 * ops["frame"]["count"] <= summary["versions_stored"] <= 3 * ops["frame"]["count"]
    d = summary["deadline"]
    assert sum(d["verdicts"].values()) == d["answers"] > 0
    assert d["exact_share"] <= d["decision_exact_share"] <= 1.0
    assert "observed in frames" in done.stdout


@pytest.mark.parametrize(
    "args",
    [
        ["--url", "http://example.com:8000"],
        ["--url", "http://10.0.0.1:8000"],
        ["--duration", "100000"],
        ["--obs-hz", "50"],
        ["--check-hz", "1"],
        ["--humans", "0"],
        ["--humans", "2", "--scenes", "3"],
        ["--scenes", "0"],
    ],
)
def test_refuses_other_hosts_and_unbounded_runs(
    args: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert load_module().main([*args, "--out", str(tmp_path / "never.json")]) == 2
    assert "refused" in capsys.readouterr().err
    assert not (tmp_path / "never.json").exists()
