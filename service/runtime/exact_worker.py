"""Exact FRTs in worker processes: one engine per process, sets sent back as bytes.

The event loop shares the GIL with any thread in its process, so an exact set (milliseconds of numpy,
onnxruntime and Python) computed in a thread slows every request answered meanwhile. Here each
worker process loads the model once (:func:`init_worker`, from the same model path as the server)
and runs :class:`ExactTask`\\ s; the result, a :class:`~reach.engine.FieldTubeSet` with its
eagerly built whole tube and the small arrays its slices are drawn from later, comes back in the
binary layout of ``reach.set_bytes`` (:func:`encode_result`, :func:`decode_result`: what a set
sends is its ``__getstate__``; the server unpickles no set), over
:class:`~service.runtime.pipe_pool.PipePool`. Conservative sets (boxes only, cheaper than a task's
round trip to a worker) are built by the server itself.

Exact-set workers run below the server (SCHED_IDLE by default, :func:`lower_priority`), so that on
a busy machine the event loop answers first and exact sets use what is left. A worker exits when its server does (even
a killed one). If worker processes cannot be started, :func:`start_pool` says why and the caller
keeps threads.
"""

from __future__ import annotations

import contextlib
import logging
import os
import struct
import threading
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from reach.contract import N_INPUTS
from reach.engine import FRTEngine
from reach.field_stack import compile_field_kernels
from reach.frames import Pose
from reach.held import compile_held_kernel
from reach.notch import NOTCH_STAGES
from reach.polygons import compile_polygon_kernel
from reach.set_bytes import SetBytesError, set_from_bytes, set_to_bytes
from reach.sets import FRTSet
from reach.speed_programme import compile_speed_programme
from reach.union import exact_union
from service.runtime.memory import freeze_start_up_objects, keep_freed_memory
from service.runtime.pipe_pool import PipePool

log = logging.getLogger("frt.exact_worker")


@dataclass
class ExactTask:
    """``engine.exact(pose, v_start, bounds, notch_cut, notch_stage, tubes_upto)``: with the given
    engine (threads) or, once pickled to a worker process, with that process's own. Bounds of
    shape [M, 8] (a multi-modal agent's modes in its set) give the union of the M exact sets
    (``reach.union.exact_union``), which the notch cut does not refine. The set's tubes
    0..``tubes_upto`` are drawn before it is returned (``FRTEngine.exact``'s ``tubes_upto``; -1:
    none but those the engine draws), so that time-indexed checks find them instead of drawing
    them on the event loop (``service.runtime.tube_demand``)."""

    pose: Pose
    v_start: float
    bounds: np.ndarray
    engine: FRTEngine | None = field(default=None, repr=False, compare=False)
    notch_cut: bool = False
    notch_stage: int | None = None
    tubes_upto: int = -1

    def __reduce__(self) -> tuple[Any, ...]:
        fields = (
            self.pose,
            self.v_start,
            self.bounds,
            None,
            self.notch_cut,
            self.notch_stage,
            self.tubes_upto,
        )
        return ExactTask, fields

    def __call__(self) -> FRTSet:
        engine = self.engine if self.engine is not None else _engine
        if engine is None:
            raise RuntimeError("no engine in this process")
        if np.ndim(self.bounds) == 2:  # a multi-modal set: one row of bounds per mode
            union = exact_union(engine, self.pose, self.v_start, self.bounds)
            if self.tubes_upto >= 0:
                union.draw_tubes(self.tubes_upto)
            return union
        return engine.exact(
            self.pose,
            self.v_start,
            self.bounds,
            notch_cut=self.notch_cut,
            notch_stage=self.notch_stage,
            tubes_upto=self.tubes_upto,
        )

    @property
    def stage(self) -> int:
        """Which notch-cut stage this task computes (0: the uncut set)."""
        return (self.notch_stage or len(NOTCH_STAGES)) if self.notch_cut else 0

    def refinement(self, result: object) -> ExactTask | None:
        """The same set cut by the next of NOTCH_STAGES, if ``result`` (this task's set) could be
        cut (``FieldTubeSet.notch_possible``) and is not cut by the last stage yet; else None."""
        if not isinstance(result, FRTSet) or not result.notch_possible:
            return None
        done = result.notch_stage
        if done >= len(NOTCH_STAGES):
            return None
        return replace(self, notch_cut=True, notch_stage=done + 1)


def init_worker(
    model_path: str, nice: int, parent_pid: int, policy: str = "idle", network: bool = True
) -> None:
    """Process initializer: load the engine (configured as the server's: cut by the network if
    ``network``), warm it, watch the parent, then take a scheduling policy below the server's.
    Start-up runs at the server's priority: on a machine kept busy by other processes a worker
    below them would take minutes to load, and the server is not ready until it has."""
    global _engine
    keep_freed_memory()
    from models.runtime import ValueModel
    from models.value_fields import ProjectionField, engine_for

    _engine = engine_for(ValueModel.load(Path(model_path)), network=network)
    # The first runtime call and contour are slower than the rest, and the partition's dynamic
    # programme and the polygons' kernel are compiled on first use (numba): take them before any
    # request.
    with contextlib.suppress(Exception):  # bounds outside a model's ranges: warm on a real set
        warm_up_task(_engine)()
    compile_speed_programme()
    compile_polygon_kernel()
    compile_field_kernels()
    compile_held_kernel()
    field = _engine.value_field
    if isinstance(field, ProjectionField):  # the runtime's arena sized for the largest sets
        field.model.evaluate_projection(np.zeros((4 * _engine.max_nodes, N_INPUTS), np.float32))
    threading.Thread(target=_exit_with_parent, args=(parent_pid,), daemon=True).start()
    freeze_start_up_objects()
    lower_priority(policy, nice)


def lower_priority(policy: str, nice: int) -> None:
    """Run this process below the server (Linux; elsewhere, or if refused, at its priority).

    * ``"idle"`` (SCHED_IDLE): only when a CPU has nothing else to run. A CPU that runs only such
      workers counts as idle when the server wakes, so the server is placed there at once instead
      of queueing beside another busy process (docs/performance.md measures the difference).
    * ``"batch"`` (SCHED_BATCH, plus ``nice``): a worker woken by a task does not preempt the
      server that sent it; it still counts as busy when the server wakes.
    """
    chosen = os.SCHED_IDLE if policy == "idle" else os.SCHED_BATCH
    with contextlib.suppress(AttributeError, OSError):
        os.sched_setscheduler(0, chosen, os.sched_param(0))
    if nice and policy != "idle":
        with contextlib.suppress(OSError):  # not permitted here: run at the server's priority
            os.nice(nice)


def warm_up_task(engine: FRTEngine) -> ExactTask:
    """An exact set of a moving car with moderate bounds (its speed inside the model's range)."""
    bounds = np.array([-0.15, -1.5, -0.15, -1.5, 0.15, 1.5, 0.15, 1.5], dtype=np.float64)
    lo, hi = engine.ranges["v_start"]
    return ExactTask(Pose(0.0, 0.0, 0.0), min(max(5.0, lo), hi), bounds, engine)


def _exit_with_parent(parent_pid: int) -> None:
    while True:
        time.sleep(1.0)
        if os.getppid() != parent_pid:
            os._exit(0)


#: What :func:`encode_result` wrote: a set alone, or a set and the seconds it took.
_SET, _TIMED_SET = b"S", b"T"
_SECONDS = struct.Struct("<d")


def encode_result(value: Any) -> bytes | None:
    """A worker's result as bytes: an exact set (``reach.set_bytes``), or the scheduler's
    ``(set, seconds)`` (``service.runtime.scheduler.timed``); None for anything else, and for a
    set the layout does not hold (a type or attribute it lacks: logged), which the pool then
    pickles."""
    frt, prefix = value, _SET
    if (
        isinstance(value, tuple)
        and len(value) == 2
        and isinstance(value[0], FRTSet)
        and isinstance(value[1], float)
    ):
        frt, prefix = value[0], _TIMED_SET + _SECONDS.pack(value[1])
    if not isinstance(frt, FRTSet):
        return None
    try:
        return set_to_bytes(frt, prefix=prefix)
    except TypeError as exc:
        log.warning("exact set sent pickled: no binary layout", extra={"error": str(exc)})
        return None


def decode_result(data: memoryview) -> Any:
    """What :func:`encode_result` wrote (``reach.set_bytes.SetBytesError`` if it is not that)."""
    kind = bytes(data[:1])
    if kind == _SET:
        return set_from_bytes(data[1:])
    if kind == _TIMED_SET and len(data) >= 1 + _SECONDS.size:
        (seconds,) = _SECONDS.unpack_from(data, 1)
        return set_from_bytes(data[1 + _SECONDS.size :]), seconds
    raise SetBytesError(f"a worker result of unknown kind {kind!r}")


#: Tasks a worker process holds at once: its next set is at hand when it has sent one back,
#: while the server's reader thread (which shares the GIL with the event loop) reads the result.
WORKER_DEPTH = 2


def start_pool(
    model_path: Path,
    workers: int,
    nice: int,
    policy: str = "idle",
    timeout_s: float = 120.0,
    network: bool = True,
    depth: int = WORKER_DEPTH,
) -> PipePool:
    """A pool of ``workers`` processes, each with the engine loaded and warmed and run below the
    server (:func:`lower_priority`), each holding up to ``depth`` tasks, that send exact sets
    back as bytes (:func:`encode_result`); raises if they cannot all be started within
    ``timeout_s``."""
    return PipePool(
        workers,
        initializer=init_worker,
        initargs=(str(model_path), nice, os.getpid(), policy, network),
        timeout_s=timeout_s,
        encode=encode_result,
        decode=decode_result,
        depth=depth,
    )
