"""Shared fixtures: the analytic test model, a live uvicorn server, in-process apps."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import httpx
import pytest

from tests.fixtures.analytic_model import write_model

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="session")
def analytic_model_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The analytic ONNX model (and its card beside it) written to a temporary directory."""
    return write_model(tmp_path_factory.mktemp("model"))


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


READY_TIMEOUT_S = 120.0
"""How long a test waits for a server to become ready: on a 2-core machine busy with other work,
loading a model and warming the exact-set workers takes tens of seconds."""


def wait_ready(
    url: str, timeout_s: float = READY_TIMEOUT_S, proc: subprocess.Popen | None = None
) -> None:
    """Until the server at ``url`` is ready: patient, since on a 2-core machine busy with other
    work a server loading the shipped model and warming its workers takes tens of seconds."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc is not None and proc.poll() is not None:
            raise RuntimeError(f"server exited with {proc.returncode}")
        try:
            if httpx.get(f"{url}/readyz", timeout=1.0).status_code == 200:
                return
        except httpx.TransportError:
            pass
        time.sleep(0.05)
    raise TimeoutError(f"{url} not ready after {timeout_s} s")


class LiveServer:
    """A real ``uvicorn service.api.app:app`` process on a free loopback port."""

    def __init__(self, env: dict[str, str], log_path: Path) -> None:
        self.port = _free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.ws_url = f"ws://127.0.0.1:{self.port}"
        self.log_path = log_path
        self._log = log_path.open("wb")
        self.proc = subprocess.Popen(
            [
                sys.executable, "-m", "uvicorn", "service.api.app:app",
                "--host", "127.0.0.1", "--port", str(self.port),
                "--log-level", "warning", "--no-access-log",
            ],
            cwd=ROOT,
            env={**os.environ, **env},
            stdout=self._log,
            stderr=subprocess.STDOUT,
        )  # fmt: skip

    def stop(self) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self._log.close()

    def logs(self) -> str:
        return self.log_path.read_text(errors="replace")


@pytest.fixture(scope="session")
def start_server(
    tmp_path_factory: pytest.TempPathFactory, analytic_model_path: Path
) -> Iterator[Callable[..., LiveServer]]:
    """Start live servers with extra ``FRT_*`` settings; all are stopped at the end of the session."""
    servers: list[LiveServer] = []

    def start(ready: bool = True, **settings: str) -> LiveServer:
        env = {"FRT_MODEL_PATH": str(analytic_model_path), "FRT_LOG_REQUESTS": "false"}
        env.update({f"FRT_{k.upper()}": str(v) for k, v in settings.items()})
        log = tmp_path_factory.mktemp("server") / "server.log"
        server = LiveServer(env, log)
        servers.append(server)
        try:
            if ready:
                wait_ready(server.url, proc=server.proc)
            else:
                wait_healthy(server.url, server.proc)
        except Exception:
            server.stop()
            raise RuntimeError(f"server did not start:\n{server.logs()}") from None
        return server

    yield start
    for server in servers:
        server.stop()


def wait_healthy(url: str, proc: subprocess.Popen, timeout_s: float = 30.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"server exited with {proc.returncode}")
        try:
            if httpx.get(f"{url}/healthz", timeout=1.0).status_code == 200:
                return
        except httpx.TransportError:
            pass
        time.sleep(0.05)
    raise TimeoutError(f"{url} not healthy after {timeout_s} s")


@pytest.fixture(scope="session")
def live_server(start_server: Callable[..., LiveServer]) -> LiveServer:
    """The shared live server with the analytic model and default settings."""
    return start_server()


@pytest.fixture
def http(live_server: LiveServer) -> Iterator[httpx.Client]:
    with httpx.Client(base_url=live_server.url, timeout=10.0) as client:
        yield client
