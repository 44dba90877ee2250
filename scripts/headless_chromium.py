"""Headless Chromium driven over the Chrome DevTools Protocol (a WebSocket, ``websockets`` only).

Used by the browser tests (``tests/test_viewer_browser.py``) and by ``scripts/demo.py
--screenshot``. :func:`find_chromium` looks for the browser (``$CHROMIUM``, Debian's
``/usr/bin/chromium``), and installs Debian's ``chromium`` package through
``scripts/ensure_chromium.sh`` where it may (root with apt-get); :func:`launch` starts it with
its own profile and a DevTools port chosen by the browser and yields a :class:`Page`.
"""

from __future__ import annotations

import base64
import contextlib
import json
import shutil
import subprocess
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
from websockets.sync.client import ClientConnection, connect

ENSURE = Path(__file__).resolve().parent / "ensure_chromium.sh"


class BrowserError(RuntimeError):
    """The browser could not be found, started or driven."""


def find_chromium(install: bool = True) -> str:
    """The path of a Chromium binary; with ``install``, apt-get installs one where none is."""
    command = ["sh", str(ENSURE)] if install else ["sh", str(ENSURE), "--no-install"]
    result = subprocess.run(command, capture_output=True, text=True, timeout=600)
    path = result.stdout.strip().splitlines()[-1] if result.stdout.strip() else ""
    if result.returncode != 0 or not path:
        raise BrowserError(result.stderr.strip() or "no chromium found")
    return path


class Page:
    """One page target: CDP calls, script evaluation, screenshots."""

    def __init__(self, ws: ClientConnection) -> None:
        self.ws = ws
        self._next = 0
        #: Uncaught exceptions and console errors of the page, as text.
        self.errors: list[str] = []

    def call(self, method: str, timeout_s: float = 30.0, **params: Any) -> dict[str, Any]:
        self._next += 1
        ident = self._next
        self.ws.send(json.dumps({"id": ident, "method": method, "params": params}))
        deadline = time.monotonic() + timeout_s
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise BrowserError(f"{method}: no answer in {timeout_s} s")
            message = json.loads(self.ws.recv(timeout=remaining))
            if message.get("id") == ident:
                if "error" in message:
                    raise BrowserError(f"{method}: {message['error']}")
                return message.get("result", {})
            self._event(message)

    def _event(self, message: dict[str, Any]) -> None:
        method = message.get("method")
        params = message.get("params", {})
        if method == "Runtime.exceptionThrown":
            details = params.get("exceptionDetails", {})
            text = details.get("exception", {}).get("description") or details.get("text")
            self.errors.append(str(text))
        elif method == "Runtime.consoleAPICalled" and params.get("type") == "error":
            self.errors.append(" ".join(str(a.get("value", a.get("description"))) for a in
                                        params.get("args", [])))  # fmt: skip

    def evaluate(self, expression: str, timeout_s: float = 30.0) -> Any:
        """The value of a JavaScript expression (promises awaited), as JSON."""
        result = self.call(
            "Runtime.evaluate",
            timeout_s=timeout_s,
            expression=expression,
            returnByValue=True,
            awaitPromise=True,
        )
        if "exceptionDetails" in result:
            details = result["exceptionDetails"]
            text = details.get("exception", {}).get("description") or details.get("text")
            raise BrowserError(f"{expression[:80]!r}: {text}")
        return result.get("result", {}).get("value")

    def wait_for(self, expression: str, timeout_s: float = 20.0, poll_s: float = 0.05) -> Any:
        """Evaluate ``expression`` until it is truthy; its value then."""
        deadline = time.monotonic() + timeout_s
        while True:
            value = self.evaluate(expression)
            if value:
                return value
            if time.monotonic() > deadline:
                raise BrowserError(f"timed out after {timeout_s} s waiting for {expression!r}")
            time.sleep(poll_s)

    def navigate(self, url: str, timeout_s: float = 20.0) -> None:
        self.call("Page.navigate", url=url)
        self.wait_for("document.readyState === 'complete'", timeout_s)

    def screenshot(self) -> bytes:
        """The viewport as PNG bytes."""
        return base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"])


def _devtools_port(profile: Path, proc: subprocess.Popen, timeout_s: float) -> int:
    marker = profile / "DevToolsActivePort"
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise BrowserError(f"chromium exited with {proc.returncode}")
        with contextlib.suppress(FileNotFoundError, ValueError, IndexError):
            return int(marker.read_text().splitlines()[0])
        time.sleep(0.05)
    raise BrowserError(f"chromium opened no DevTools port in {timeout_s} s")


@contextlib.contextmanager
def launch(
    binary: str, width: int = 1280, height: int = 800, timeout_s: float = 30.0
) -> Iterator[Page]:
    """Start headless Chromium, yield its first page (viewport ``width`` x ``height``, scale 1)."""
    profile = Path(tempfile.mkdtemp(prefix="frt-chromium-"))
    proc = subprocess.Popen(
        [
            binary, "--headless=new", "--no-sandbox", "--disable-gpu",
            "--disable-dev-shm-usage", "--no-first-run", "--no-default-browser-check",
            "--disable-extensions", "--disable-background-networking", "--mute-audio",
            "--remote-debugging-address=127.0.0.1", "--remote-debugging-port=0",
            f"--user-data-dir={profile}", f"--window-size={width},{height}", "about:blank",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        port = _devtools_port(profile, proc, timeout_s)
        targets = httpx.get(f"http://127.0.0.1:{port}/json/list", timeout=5.0).json()
        page_url = next(t["webSocketDebuggerUrl"] for t in targets if t.get("type") == "page")
        with connect(page_url, max_size=64 * 2**20, open_timeout=timeout_s) as ws:
            page = Page(ws)
            page.call("Runtime.enable")
            page.call("Page.enable")
            page.call(
                "Emulation.setDeviceMetricsOverride",
                width=width,
                height=height,
                deviceScaleFactor=1,
                mobile=False,
            )
            yield page
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        shutil.rmtree(profile, ignore_errors=True)
