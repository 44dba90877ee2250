"""A process pool that costs its parent little: one pipe per worker, one reader thread.

``concurrent.futures.ProcessPoolExecutor`` moves every task through a queue-management thread and a
feeder thread in the parent, each of which must take the GIL from the event loop: per task, about
what a conservative set costs to compute (docs/performance.md). In :class:`PipePool` the submitting thread pickles a task and writes it straight to an idle
worker's pipe, and a single reader thread waits on all pipes at once and completes the futures.

Workers are spawned, run an initializer once, report ready, then serve tasks one at a time until they
read ``None`` or their pipe closes. A worker that dies breaks the pool (:class:`BrokenExecutor` for
its task, every queued one and every later submit), as with ``ProcessPoolExecutor``.

Tasks and errors travel pickled. A result travels as the pool's ``encode`` writes it, when it
writes it (bytes, read back by ``decode`` in the parent without unpickling anything: the exact
sets, ``service.runtime.exact_worker``), and pickled otherwise; the first byte of every message
from a worker says which.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import pickle
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import BrokenExecutor, Executor, Future
from dataclasses import dataclass, field
from multiprocessing.connection import Connection, wait
from typing import Any

#: Protocol 4, not 5: with 5 every numpy array comes back viewing its payload through a memoryview
#: and a managed buffer, two objects the garbage collector tracks (36 per exact set, ~9 000 with
#: the FRT cache full: they lengthened every full collection); with 4 the arrays own their copy.
_PROTOCOL = 4
#: The first byte of a message from a worker: a pickled ``(ok, value)``, or a result as the
#: pool's ``encode`` wrote it.
_PICKLED, _ENCODED = b"P", b"E"

#: Writes a result as bytes, or None to leave it pickled (runs in the workers: module level).
Encode = Callable[[Any], bytes | None]
#: Reads back what ``Encode`` wrote (in the parent).
Decode = Callable[[memoryview], Any]


def _serve(
    conn: Connection,
    initializer: Callable[..., None],
    initargs: tuple[Any, ...],
    encode: Encode | None = None,
) -> None:
    """A worker process: initialise, say ready, then run pickled ``(fn, args)`` until told to stop;
    a result ``encode`` writes goes back as those bytes, any other outcome pickled."""
    initializer(*initargs)
    conn.send_bytes(_PICKLED + pickle.dumps(("ready", os.getpid()), _PROTOCOL))
    while True:
        try:
            message = pickle.loads(conn.recv_bytes())
        except (EOFError, OSError):
            return
        if message is None:
            return
        fn, args = message
        try:
            outcome: tuple[bool, Any] = (True, fn(*args))
        except BaseException as exc:  # sent back to the caller's future
            outcome = (False, exc)
        conn.send_bytes(_outcome_bytes(outcome, encode))


def _outcome_bytes(outcome: tuple[bool, Any], encode: Encode | None) -> bytes:
    """A worker's message for ``outcome``: the result as ``encode`` writes it, else pickled."""
    ok, value = outcome
    if ok and encode is not None:
        try:
            encoded = encode(value)
        except Exception as exc:  # a result the encoder refuses: sent back as the error
            outcome = (False, RuntimeError(f"unencodable result: {exc!r}"))
        else:
            if encoded is not None:
                return _ENCODED + encoded
    try:
        return _PICKLED + pickle.dumps(outcome, _PROTOCOL)
    except Exception as exc:  # an unpicklable result or exception
        return _PICKLED + pickle.dumps(
            (False, RuntimeError(f"unpicklable outcome: {exc!r}")), _PROTOCOL
        )


@dataclass(eq=False)
class _Worker:
    process: Any  # multiprocessing.context.SpawnProcess
    conn: Connection
    #: The tasks sent to it and not answered yet, oldest first (it answers in order).
    futures: deque[Future[Any]] = field(default_factory=deque)


class PipePool(Executor):
    """``workers`` spawned processes, each initialised by ``initializer(*initargs)``; raises if they
    are not all ready within ``timeout_s``. Results that ``encode`` writes come back through
    ``decode`` (a result that does not decode fails its future with the decoder's error).

    A worker holds up to ``depth`` tasks in its pipe (the least busy worker takes the next):
    with 2, it reads its next task as soon as it has written a result, instead of waiting while
    this process, whose threads share one GIL with a busy event loop, reads the result and sends
    the next task."""

    def __init__(
        self,
        workers: int,
        initializer: Callable[..., None],
        initargs: tuple[Any, ...] = (),
        timeout_s: float = 120.0,
        encode: Encode | None = None,
        decode: Decode | None = None,
        depth: int = 1,
    ) -> None:
        if (encode is None) != (decode is None):
            raise ValueError("encode and decode go together")
        if depth < 1:
            raise ValueError("depth must be at least 1")
        self.depth = depth
        context = multiprocessing.get_context("spawn")
        self._decode = decode
        self._lock = threading.Lock()
        self._queue: deque[tuple[Future[Any], bytes]] = deque()
        self._broken: str | None = None
        self._closed = False
        self._workers: list[_Worker] = []
        wake_reader, self._wake = context.Pipe(duplex=False)
        self._wake_reader = wake_reader
        try:
            for _ in range(workers):
                parent, child = context.Pipe()
                process = context.Process(
                    target=_serve, args=(child, initializer, initargs, encode), daemon=True
                )
                process.start()
                child.close()
                self._workers.append(_Worker(process, parent))
            deadline = time.monotonic() + timeout_s
            for worker in self._workers:
                if not worker.conn.poll(max(deadline - time.monotonic(), 0.0)):
                    raise TimeoutError(f"a worker process was not ready within {timeout_s:g} s")
                self._outcome(worker.conn.recv_bytes())  # ("ready", pid)
        except BaseException:
            self._stop_processes()
            raise
        self._reader = threading.Thread(target=self._read, name="pipe-pool-reader", daemon=True)
        self._reader.start()

    @property
    def pids(self) -> list[int]:
        return [w.process.pid for w in self._workers]

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future[Any]:
        if kwargs:
            raise TypeError("PipePool.submit takes positional arguments only")
        payload = pickle.dumps((fn, args), _PROTOCOL)
        future: Future[Any] = Future()
        with self._lock:
            if self._broken is not None:
                raise BrokenExecutor(self._broken)
            if self._closed:
                raise RuntimeError("cannot submit after shutdown")
            self._queue.append((future, payload))
            self._feed_locked()
        return future

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
            if cancel_futures:
                while self._queue:
                    self._queue.popleft()[0].cancel()
            for worker in self._workers:  # read after the task a worker may be running
                with contextlib.suppress(OSError):
                    worker.conn.send_bytes(pickle.dumps(None, _PROTOCOL))
        if wait:
            for worker in self._workers:
                worker.process.join(timeout=30.0)
        self._stop_processes()

    # ------------------------------------------------------------------ internals
    def _feed_locked(self) -> None:
        """Hand queued tasks to the least busy workers holding fewer than ``depth`` (caller
        holds the lock)."""
        while self._queue:
            worker = min(self._workers, key=lambda w: len(w.futures))
            if len(worker.futures) >= self.depth:
                return
            future, payload = self._queue.popleft()
            if not future.set_running_or_notify_cancel():
                continue
            worker.futures.append(future)
            try:
                worker.conn.send_bytes(payload)
            except OSError:  # the worker is gone; the reader breaks the pool on its EOF
                worker.futures.pop()
                future.set_exception(BrokenExecutor("a worker process died"))

    def _read(self) -> None:
        by_conn = {w.conn: w for w in self._workers}
        while by_conn:
            for conn in wait([*by_conn, self._wake_reader]):
                if conn is self._wake_reader:
                    return
                worker = by_conn[conn]  # type: ignore[index]
                try:
                    data = worker.conn.recv_bytes()
                except (EOFError, OSError):
                    del by_conn[worker.conn]
                    self._worker_gone(worker)
                    continue
                try:
                    ok, value = self._outcome(data)
                except Exception as exc:  # a result that does not unpickle or decode here
                    ok, value = False, exc
                with self._lock:
                    future = worker.futures.popleft() if worker.futures else None
                    self._feed_locked()
                if future is not None:
                    if ok:
                        future.set_result(value)
                    else:
                        future.set_exception(value)

    def _outcome(self, data: bytes) -> tuple[bool, Any]:
        """``(ok, value)`` of a worker's message: decoded, or unpickled (our own processes)."""
        body = memoryview(data)[1:]
        if data[:1] == _ENCODED and self._decode is not None:
            return True, self._decode(body)
        if data[:1] == _PICKLED:
            return pickle.loads(body)  # type: ignore[no-any-return]
        raise RuntimeError(f"a worker message of unknown kind {bytes(data[:1])!r}")

    def _worker_gone(self, worker: _Worker) -> None:
        with self._lock:
            if self._closed and not worker.futures:
                return  # stopped as asked
            self._broken = "a worker process died"
            failed = list(worker.futures)
            worker.futures.clear()
            failed += [f for f, _ in self._queue if f.set_running_or_notify_cancel()]
            self._queue.clear()
        for future in failed:
            future.set_exception(BrokenExecutor("a worker process died"))

    def _stop_processes(self) -> None:
        for worker in self._workers:
            if worker.process.is_alive():
                worker.process.terminate()
                worker.process.join(timeout=5.0)
        with contextlib.suppress(OSError):
            self._wake.send_bytes(b"")
