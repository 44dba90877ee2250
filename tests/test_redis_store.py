"""The Redis agent store against a real redis-server on a loopback port, started by the test.

redis-server comes from Debian's packages (installed here if missing, as CI runs as root on Debian).
The helpers at the top (:func:`require_commands`, :class:`RedisServer`, :func:`free_port`) are
shared with the deployment and scale-out tests.
"""

from __future__ import annotations

import asyncio
import json
import os
import shutil
import signal
import socket
import subprocess
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from service.runtime.stores import AgentState, AgentStore, StoreFullError, make_store
from service.wire.errors import FieldError, ServiceUnavailableError, StaleTimestampError

# ----------------------------------------------------------------------------- shared helpers

#: Debian package that provides each command the deployment tests use.
DEBIAN_PACKAGES = {
    "redis-server": "redis-server",
    "nginx": "nginx",
    "docker-compose": "docker-compose",
}
_SBIN_PATH = os.pathsep.join([os.environ.get("PATH", ""), "/usr/sbin", "/usr/local/sbin", "/sbin"])


def which(command: str) -> str | None:
    """``shutil.which`` that also looks in the sbin folders (nginx lives in /usr/sbin)."""
    return shutil.which(command, path=_SBIN_PATH)


def require_commands(*commands: str) -> dict[str, str]:
    """Paths of ``commands``, installing their Debian packages with apt-get if any is missing.

    Skips the calling test only when apt-get is not there or we are not root (not a Debian CI
    machine); an apt-get that is there but fails is a test failure, not a skip.
    """
    missing = [c for c in commands if which(c) is None]
    if missing:
        if shutil.which("apt-get") is None or os.geteuid() != 0:
            pytest.skip(f"{', '.join(missing)} not installed and apt-get (as root) unavailable")
        packages = sorted({DEBIAN_PACKAGES[c] for c in missing})
        env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
        install = ["apt-get", "install", "-y", "-q", "--no-install-recommends", *packages]
        done = subprocess.run(install, env=env, capture_output=True, text=True, timeout=600)
        if done.returncode != 0:  # a new machine may have no package lists yet
            subprocess.run(["apt-get", "update", "-q"], env=env, capture_output=True, timeout=600)
            done = subprocess.run(install, env=env, capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, f"apt-get install {packages} failed:\n{done.stderr[-2000:]}"
    paths = {c: which(c) for c in commands}
    assert all(paths.values()), f"still missing after apt-get: {paths}"
    return {c: p for c, p in paths.items() if p is not None}


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class RedisServer:
    """A redis-server process on 127.0.0.1 with its files in ``directory``."""

    def __init__(self, directory: Path, *, appendonly: bool = False) -> None:
        self.binary = require_commands("redis-server")["redis-server"]
        self.directory = directory
        self.appendonly = appendonly
        self.port = free_port()
        self.proc: subprocess.Popen[bytes] | None = None

    @property
    def url(self) -> str:
        return f"redis://127.0.0.1:{self.port}/0"

    def start(self, timeout_s: float = 15.0) -> None:
        """Start (or restart, on the same port and files) and wait until it answers PING."""
        args = [
            self.binary,
            "--port", str(self.port),
            "--bind", "127.0.0.1",
            "--dir", str(self.directory),
            "--appendonly", "yes" if self.appendonly else "no",
            "--appendfsync", "always",
            "--save", "",
            "--daemonize", "no",
            "--logfile", str(self.directory / "redis.log"),
        ]  # fmt: skip
        self.proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"redis-server exited: {self.log_tail()}")
            if self._answers_ping():
                return
            time.sleep(0.02)
        raise RuntimeError(f"redis-server did not answer in {timeout_s}s: {self.log_tail()}")

    def kill(self, sig: int = signal.SIGKILL) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(sig)
            self.proc.wait(timeout=10)

    def log_tail(self) -> str:
        log = self.directory / "redis.log"
        return log.read_text()[-2000:] if log.exists() else "(no log)"

    def _answers_ping(self) -> bool:
        try:
            with socket.create_connection(("127.0.0.1", self.port), timeout=0.5) as s:
                s.sendall(b"PING\r\n")
                return s.recv(64).startswith(b"+PONG")  # -LOADING while replaying the AOF
        except OSError:
            return False


# ----------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def redis_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RedisServer]:
    server = RedisServer(tmp_path_factory.mktemp("redis"))
    server.start()
    yield server
    server.kill(signal.SIGTERM)


def make(server: RedisServer, **kwargs: Any) -> Any:
    """A RedisAgentStore on ``server`` with its own key prefix (tests don't see each other)."""
    from service.runtime.stores.redis import RedisAgentStore

    options: dict[str, Any] = {"ttl_s": 60.0, "max_agents": 100, "prefix": f"t{uuid.uuid4().hex}:"}
    options.update(kwargs)
    return RedisAgentStore(server.url, **options)


def state(agent_id: str, timestamp: float, **config: Any) -> AgentState:
    return AgentState(
        agent_id=agent_id,
        timestamp=timestamp,
        x=1.5,
        y=-2.25,
        heading=0.1,
        speed=4.2,
        belief={"betas": [0.03, 1.0], "log_probs": [-0.6931471805599453, -0.6931471805599453]},
        prediction={"dt": 0.5, "mean": [[0.0, 0.1]], "cov": [[[0.01, 0.0], [0.0, 0.25]]]},
        control_bounds=[-0.3, -1.0, -0.3, -1.0, 0.3, 1.0, 0.3, 1.0],
        config=dict(config),
    )


def put(s: AgentState) -> Any:
    """An update function that ignores the current state and writes ``s``."""
    return lambda _current: s


def bump(
    current: AgentState | None, agent_id: str = "a", timestamp: float | None = None
) -> AgentState:
    """Increment a counter kept in the state: a lost update shows as a missing increment."""
    new = current or state(agent_id, 0.0, n=0, log=[])
    new.config["n"] += 1
    new.frt_version += 1
    if timestamp is not None:
        new.timestamp = timestamp
        new.config["log"].append(timestamp)
    return new


def run(coro: Any) -> Any:
    return asyncio.run(coro)


# ----------------------------------------------------------------------------- tests

pytestmark = pytest.mark.timeout(120)


def test_make_store_picks_redis_from_the_url(redis_server: RedisServer) -> None:
    from service.runtime.stores.redis import RedisAgentStore

    async def go() -> None:
        store = make_store(redis_server.url, ttl_s=10.0, max_agents=5)
        assert isinstance(store, RedisAgentStore)
        assert isinstance(store, AgentStore)
        assert await store.count() >= 0
        await store.close()

    run(go())


def test_roundtrip_is_json_with_the_ttl(redis_server: RedisServer) -> None:
    import redis

    async def go() -> None:
        store = make(redis_server, ttl_s=30.0)
        written = await store.update("car-1", put(state("car-1", 12.5, gamma=0.1)), timestamp=12.5)
        assert written == state("car-1", 12.5, gamma=0.1)
        assert await store.get("car-1") == written
        assert await store.get("unknown") is None
        assert await store.get_many(["unknown", "car-1"]) == [None, written]
        key = store.key("car-1")
        await store.close()
        raw = redis.Redis.from_url(redis_server.url)
        assert json.loads(raw.get(key)) == written.to_dict()  # plain JSON, never pickle
        assert 29_000 < raw.pttl(key) <= 30_000
        raw.close()

    run(go())


def test_timestamps_must_increase(redis_server: RedisServer) -> None:
    async def go() -> None:
        store = make(redis_server)
        await store.update("a", put(state("a", 1.0)), timestamp=1.0)
        for stale in (1.0, 0.5):
            with pytest.raises(StaleTimestampError) as info:
                await store.update("a", put(state("a", stale)), timestamp=stale)
            assert info.value.status == 409 and info.value.last == 1.0
        await store.update("a", put(state("a", 1.0000000001)), timestamp=1.0000000001)
        assert (await store.get("a")).timestamp == 1.0000000001
        await store.update("a", put(state("a", 0.0)))  # no timestamp: no check
        await store.close()

    run(go())


def test_a_failing_update_writes_nothing(redis_server: RedisServer) -> None:
    def fail(_current: AgentState | None) -> AgentState:
        raise FieldError("prediction.cov.0", "not positive definite")

    async def go() -> None:
        store = make(redis_server)
        with pytest.raises(FieldError):
            await store.update("a", fail, timestamp=1.0)
        assert await store.get("a") is None and await store.count() == 0
        await store.update("a", put(state("a", 1.0)), timestamp=1.0)
        with pytest.raises(FieldError):
            await store.update("a", fail, timestamp=2.0)
        assert await store.get("a") == state("a", 1.0)
        await store.close()

    run(go())


def test_agents_expire_with_the_ttl_and_updates_refresh_it(redis_server: RedisServer) -> None:
    async def go() -> None:
        # Generous margins (TTL 2 s, steps of 1.2 s): a loaded CI machine may oversleep.
        store = make(redis_server, ttl_s=2.0)
        await store.update("a", put(state("a", 1.0)))
        await store.update("b", put(state("b", 1.0)))
        await asyncio.sleep(1.2)
        await store.update("b", put(state("b", 2.0)))  # refreshes b only
        await asyncio.sleep(1.2)
        assert await store.get("a") is None
        assert await store.get("b") is not None
        assert await store.ids() == ["b"] and await store.count() == 1
        await asyncio.sleep(1.2)
        assert await store.get("b") is None and await store.count() == 0
        await store.close()

    run(go())


def test_max_agents(redis_server: RedisServer) -> None:
    async def go() -> None:
        store = make(redis_server, max_agents=2, ttl_s=0.5)
        await store.update("a", put(state("a", 1.0)))
        await store.update("b", put(state("b", 1.0)))
        with pytest.raises(StoreFullError) as info:
            await store.update("c", put(state("c", 1.0)))
        assert info.value.status == 503
        assert await store.get("c") is None
        await store.update("a", put(state("a", 2.0)))  # known agents still update
        assert await store.delete("b") is True
        assert await store.delete("b") is False
        await store.update("c", put(state("c", 1.0)))  # room again after a delete
        assert sorted(await store.ids()) == ["a", "c"]
        await asyncio.sleep(0.6)
        await store.update("d", put(state("d", 1.0)))  # and after the TTL
        await store.update("e", put(state("e", 1.0)))
        assert await store.count() == 2
        await store.close()

    run(go())


def test_two_replicas_lose_no_update(redis_server: RedisServer) -> None:
    """Two stores (two replicas, each with its own connections) hammer one agent at once."""

    async def go() -> None:
        first = make(redis_server)
        second = make(redis_server, prefix=first._prefix)  # same keys, other connections
        per_replica = 150
        await asyncio.gather(
            *(s.update("a", bump) for _ in range(per_replica) for s in (first, second))
        )
        final = await first.get("a")
        assert final is not None and final.config["n"] == 2 * per_replica
        assert final.frt_version == 1 + 2 * per_replica
        assert first.conflicts + second.conflicts > 0, "the updates never raced"
        print(f"\n{2 * per_replica} updates, {first.conflicts + second.conflicts} CAS retries")
        await first.close()
        await second.close()

    run(go())


def test_two_replicas_with_timestamps_keep_every_accepted_one(redis_server: RedisServer) -> None:
    """Interleaved timestamps from two replicas: each is accepted or refused (409), none lost."""

    async def go() -> None:
        first = make(redis_server)
        second = make(redis_server, prefix=first._prefix)
        accepted: list[float] = []

        async def send(store: Any, ts: float) -> None:
            try:
                await store.update("a", lambda cur: bump(cur, "a", ts), timestamp=ts)
                accepted.append(ts)
            except StaleTimestampError:
                pass

        await asyncio.gather(*(send((first, second)[i % 2], float(i)) for i in range(1, 201)))
        final = await first.get("a")
        assert final is not None
        assert final.config["log"] == sorted(accepted)  # every accepted one, in order
        assert final.config["n"] == len(accepted) and final.timestamp == max(accepted)
        await first.close()
        await second.close()

    run(go())


def test_update_many_is_update_of_each_agent(redis_server: RedisServer) -> None:
    """One read and one script for a frame's agents: each written as ``update`` writes it, the
    refused ones (stale, full, their function's APIError) answered in place and unchanged."""

    def fail(_current: AgentState | None) -> AgentState:
        raise FieldError("prediction.cov.0", "not positive definite")

    async def go() -> None:
        store = make(redis_server, max_agents=4)
        await store.update("old", put(state("old", 5.0)), timestamp=5.0)
        await store.update("bad", put(state("bad", 1.0)), timestamp=1.0)
        results = await store.update_many(
            [
                ("keep", put(state("keep", 2.0)), 2.0),
                ("old", put(state("old", 4.0)), 4.0),
                ("bad", fail, 2.0),
                ("new", put(state("new", 2.0)), 2.0),
                ("full", put(state("full", 2.0)), 2.0),
            ]
        )
        assert [type(r).__name__ for r in results] == [
            "AgentState", "StaleTimestampError", "FieldError", "AgentState", "StoreFullError",
        ]  # fmt: skip
        assert results[0] == state("keep", 2.0) and results[3] == state("new", 2.0)
        assert results[1].last == 5.0  # type: ignore[union-attr]
        got = await store.get_many(["keep", "old", "bad", "new", "full"])
        assert got == [state("keep", 2.0), state("old", 5.0), state("bad", 1.0), results[3], None]
        assert await store.count() == 4
        with pytest.raises(ValueError):
            await store.update_many([("a", put(state("a", 1.0)), None)] * 2)
        await store.close()

    run(go())


def test_update_many_against_another_replica_loses_nothing(redis_server: RedisServer) -> None:
    """Frames on one replica, single updates of the same agents on another: an agent the other
    replica wrote between the frame's read and its script is updated again on its own."""

    async def go() -> None:
        first = make(redis_server)
        second = make(redis_server, prefix=first._prefix)
        ids = [f"a{i}" for i in range(5)]
        rounds = 40

        async def frames() -> None:
            for _ in range(rounds):
                await first.update_many([(a, lambda cur, a=a: bump(cur, a), None) for a in ids])

        async def singles() -> None:
            for _ in range(rounds):
                for a in ids:
                    await second.update(a, lambda cur, a=a: bump(cur, a))

        await asyncio.gather(frames(), singles())
        final = await first.get_many(ids)
        assert [s.config["n"] for s in final] == [2 * rounds] * len(ids)
        print(f"\n{first.conflicts + second.conflicts} CAS retries")
        await first.close()
        await second.close()

    run(go())


def test_update_many_with_a_lost_reply_applies_each_agent_once(redis_server: RedisServer) -> None:
    import redis.exceptions

    async def go() -> None:
        store = make(redis_server)
        await store.update("a", bump)
        real = store._update_many_script

        async def applied_then_disconnected(**kwargs: Any) -> Any:
            await real(**kwargs)
            raise redis.exceptions.ConnectionError("connection lost after EVALSHA")

        store._update_many_script = applied_then_disconnected
        results = await store.update_many(
            [("a", bump, None), ("b", lambda cur: bump(cur, "b"), None)]
        )
        assert [r.config["n"] for r in results] == [2, 1]  # type: ignore[union-attr]
        assert [s.config["n"] for s in await store.get_many(["a", "b"])] == [2, 1]
        await store.close()

    run(go())


def test_a_lost_reply_is_not_applied_twice(redis_server: RedisServer) -> None:
    import redis.exceptions

    async def go() -> None:
        store = make(redis_server)
        await store.update("a", bump)
        real = store._update_script
        calls = 0

        async def applied_then_disconnected(**kwargs: Any) -> Any:
            nonlocal calls
            calls += 1
            result = await real(**kwargs)
            if calls == 1:
                raise redis.exceptions.ConnectionError("connection lost after EVALSHA")
            return result

        store._update_script = applied_then_disconnected
        result = await store.update("a", bump)
        assert calls == 1 and result.config["n"] == 2
        assert (await store.get("a")).config["n"] == 2
        await store.close()

    run(go())


def test_an_unconfirmed_write_past_the_wait_is_a_504(redis_server: RedisServer) -> None:
    """Sent, never answered, Redis not back in time: the outcome is unknown, so not a 503."""
    import redis.exceptions

    from service.runtime.stores.redis import StoreOutcomeUnknownError

    async def go() -> None:
        store = make(redis_server, unavailable_wait_s=0.2)

        async def lost(**_kwargs: Any) -> Any:
            raise redis.exceptions.ConnectionError("connection lost after EVALSHA")

        store._update_script = lost
        with pytest.raises(StoreOutcomeUnknownError) as info:
            await store.update("a", bump)
        assert info.value.status == 504 and "resend" in info.value.detail
        await store.close()

    run(go())


def test_redis_down_is_a_503_not_a_500() -> None:
    from service.runtime.stores.redis import RedisAgentStore

    async def go() -> None:
        store = RedisAgentStore(
            f"redis://127.0.0.1:{free_port()}/0", ttl_s=1.0, max_agents=1, unavailable_wait_s=0.2
        )
        start = time.monotonic()
        with pytest.raises(ServiceUnavailableError) as info:
            await store.get("a")
        assert info.value.status == 503 and 0.15 < time.monotonic() - start < 2.0
        with pytest.raises(ServiceUnavailableError):
            await store.update("a", bump)
        assert await store.ping() is False
        await store.close()

    run(go())


def test_state_survives_a_redis_crash_with_append_only_persistence(tmp_path: Path) -> None:
    server = RedisServer(tmp_path, appendonly=True)
    server.start()
    try:

        async def go() -> None:
            store = make(server, unavailable_wait_s=10.0)
            for _ in range(5):
                await store.update("a", bump)
            server.kill(signal.SIGKILL)
            # An update that starts while Redis is down waits for it (within the budget).
            restart = asyncio.get_running_loop().run_in_executor(None, _start_later, server, 0.3)
            result = await store.update("a", bump)
            await restart
            assert result.config["n"] == 6
            assert (await store.get("a")).config["n"] == 6
            await store.close()

        run(go())
    finally:
        server.kill(signal.SIGTERM)


def _start_later(server: RedisServer, delay_s: float) -> None:
    time.sleep(delay_s)
    server.start()
