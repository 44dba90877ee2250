"""The real service for the experiments: a uvicorn subprocess on a free loopback port, or a URL.

Every experiment talks to the service only through the client SDK (``frt_client.FRTClient``), the
way a planner would. :func:`connect` starts ``uvicorn service.api.app:app`` with the given model unless
a URL is given, waits until the model is loaded, and stops the process on exit.
"""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

from frt_client import FRTClient

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_MODEL = ROOT / "models" / "frt_unicycle.onnx"
#: Long enough for the slowest exact FRT on a busy 2-core machine: the experiments want exact
#: answers, never the service's conservative fallback (which the results would then record).
DEADLINE_MS = 60_000.0
CLIENT_TIMEOUT_S = 120.0
#: The longest wait one ``GET /v1/agents/{id}?wait_frt_ms=N`` accepts (service/routes/agents.py).
WAIT_FRT_MAX_MS = 10_000.0


def free_port() -> int:
    """A free TCP port on the loopback interface."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextlib.contextmanager
def local_server(
    model: Path, log_path: Path, workers: int = 1, ready_timeout_s: float = 120.0
) -> Iterator[str]:
    """Run ``uvicorn service.api.app:app`` on a free loopback port; yield its URL.

    ``workers`` is the service's ``FRT_FRT_WORKERS`` (workers computing exact FRTs). Server logs
    go to ``log_path``.
    """
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    env = {
        **os.environ,
        "FRT_MODEL_PATH": str(Path(model).resolve()),
        "FRT_LOG_REQUESTS": "false",
        "FRT_FRT_WORKERS": str(workers),
        # contours and the stateless FRT wait this long for the exact set (default 5 s)
        "FRT_EXACT_TIMEOUT_S": "60",
    }
    log_path.parent.mkdir(parents=True, exist_ok=True)
    with log_path.open("wb") as log:
        proc = subprocess.Popen(
            [
                sys.executable, "-m", "uvicorn", "service.api.app:app",
                "--host", "127.0.0.1", "--port", str(port),
                "--log-level", "warning", "--no-access-log",
            ],
            cwd=ROOT,
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
        )  # fmt: skip
        try:
            _wait_ready(url, proc, ready_timeout_s, log_path)
            yield url
        finally:
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def _wait_ready(url: str, proc: subprocess.Popen, timeout_s: float, log_path: Path) -> None:
    deadline = time.monotonic() + timeout_s
    with FRTClient(url, timeout=2.0) as client:
        while time.monotonic() < deadline:
            if proc.poll() is not None:
                raise RuntimeError(
                    f"service exited with {proc.returncode}:\n{log_path.read_text(errors='replace')}"
                )
            try:
                if client.ready().ready:
                    return
            except Exception:  # not listening yet
                pass
            time.sleep(0.1)
    raise TimeoutError(f"service at {url} not ready after {timeout_s} s (log: {log_path})")


def wait_exact(client: FRTClient, agent_id: str, timeout_s: float = 120.0) -> None:
    """Block until the service has the exact FRT of the agent's current version.

    A collision check that arrives while the exact set is still queued is answered at once from
    the conservative outer bound (API.md, "Collision check"); a planner that wants the exact answer,
    as these experiments do, waits for it first: ``GET /v1/agents/{id}?wait_frt_ms=N`` answers as
    soon as the exact set is ready (the SDK's ``get_agent(..., wait_frt_ms=N)``). One wait is at
    most ``WAIT_FRT_MAX_MS`` (the API's limit).
    """
    end = time.monotonic() + timeout_s
    while True:
        remaining_ms = (end - time.monotonic()) * 1000.0
        if remaining_ms <= 0.0:
            raise TimeoutError(f"exact FRT of {agent_id} not ready after {timeout_s} s")
        wait_ms = min(remaining_ms, WAIT_FRT_MAX_MS)
        if client.get_agent(agent_id, wait_frt_ms=wait_ms).frt_ready:
            return


@contextlib.contextmanager
def connect(
    url: str | None, model: Path = DEFAULT_MODEL, log_path: Path | None = None
) -> Iterator[FRTClient]:
    """An SDK client to ``url``, or to a local service started on ``model`` when ``url`` is None."""
    if url is not None:
        with FRTClient(url, timeout=CLIENT_TIMEOUT_S) as client:
            client.wait_ready(timeout_s=60.0)
            yield client
        return
    log = log_path or Path(tempfile.gettempdir()) / "frt-experiments-service.log"
    with (
        local_server(model, log) as local_url,
        FRTClient(local_url, timeout=CLIENT_TIMEOUT_S) as client,
    ):
        yield client
