"""Loading the served model at start-up: the ONNX network and its card, the engine, the kernels
compiled and the worker processes warmed before the service reports ready.

A missing or broken model never stops the service: :func:`load_model` returns why, and the
model-dependent routes answer 503 with it.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from models.runtime import ModelCard, ValueModel
from models.value_fields import engine_for, network_decision
from reach.batch import compile_batch_kernels
from reach.engine import FRTEngine
from reach.envelope_lp import compile_envelope_kernels
from reach.field_stack import compile_field_kernels
from reach.held import compile_held_kernel
from reach.packed_rings import compile_ring_kernels
from reach.polygons import compile_polygon_kernel
from reach.sweep_boxes import compile_sweep_kernels
from reach.witness import compile_witness_kernel
from service.runtime.exact_worker import ExactTask, start_pool, warm_up_task
from service.runtime.refiner import Refinement
from service.runtime.scheduler import FRTScheduler, timed
from service.runtime.settings import Settings
from service.runtime.tube_builder import TubeBuilder
from service.wire.schemas import ActiveParts, NetworkPart

log = logging.getLogger("frt.services")


@dataclass(frozen=True)
class LoadedModel:
    """The served model: its engine and card, which parts build the sets, and whether worker
    processes draw the tubes checks ask for."""

    engine: FRTEngine
    card: ModelCard
    parts: ActiveParts
    tubes_in_workers: bool


def load_model(
    settings: Settings, scheduler: FRTScheduler, tubes: TubeBuilder
) -> LoadedModel | str:
    """Load ``settings.model_path`` (blocking), teach ``tubes`` what a tube costs here and move
    ``scheduler`` onto worker processes where configured; the reason if the model cannot load."""
    path = settings.model_path
    start = time.perf_counter()
    try:
        model = ValueModel.load(path)
        network, reason = network_decision(model.card, settings.network)
        engine = engine_for(model, network=network)
        # Before readiness: a first call would stall the event loop (threads compute there).
        compile_polygon_kernel()
        compile_field_kernels()
        compile_held_kernel()
        compile_ring_kernels()
        compile_batch_kernels()
        compile_sweep_kernels()
        compile_envelope_kernels()
        compile_witness_kernel()
    except Exception as exc:  # a missing or broken model must not stop the service
        log.error("model not loaded", extra={"model_path": str(path), "error": str(exc)})
        return f"model not loaded: {exc}"
    # What a tube costs here, before a first check has to guess; a model whose ranges exclude
    # the warm-up setting keeps the first guess.
    with contextlib.suppress(Exception):
        tubes.learn_cost(warm_up_task(engine)())
    on_processes = settings.frt_executor == "process" and start_worker_processes(
        settings, scheduler, path, engine, network
    )
    notch_cut = settings.frt_notch_cut and on_processes
    if notch_cut:
        # Not on threads: 0.1-1 s of work per refinement would hold the event loop's GIL.
        scheduler.refinement = refine_by_notch_cut
    parts = ActiveParts(
        geometry=["outer_bound", *(["notch_partition"] if notch_cut else [])],
        value_network=NetworkPart(loaded=True, active=network, reason=reason),
        bounds_rule=settings.bounds_rule,
    )
    log.info(
        "model loaded",
        extra={
            "model": model.card.name,
            "model_path": str(path),
            "seconds": round(time.perf_counter() - start, 3),
        },
    )
    return LoadedModel(engine, model.card, parts, settings.frt_draw_tubes and on_processes)


def start_worker_processes(
    settings: Settings, scheduler: FRTScheduler, path: Path, engine: FRTEngine, network: bool
) -> bool:
    """Compute exact sets in worker processes (their engines loaded and warmed before the server
    reports ready); if they cannot start, stay on threads and say why. Whether they started."""
    start = time.perf_counter()
    workers = scheduler.workers
    try:
        pool = start_pool(
            path, workers, settings.frt_worker_nice, settings.frt_worker_policy, network=network
        )
    except Exception as exc:
        log.warning(
            "FRT worker processes not started: computing exact sets on threads",
            extra={"error": repr(exc)},
        )
        return False
    # A worker's first result costs more than the next ones (the first pickling there and
    # unpickling here): one per worker before any request.
    with contextlib.suppress(Exception):
        for warm in [pool.submit(timed, warm_up_task(engine)) for _ in range(workers)]:
            frt, _ = warm.result(60.0)
        for kind, t in (("tube", None), ("slice", 1.0)):  # and the first contours drawn here
            frt.geojson(kind, t, settings.collision_radius)
    scheduler.use_executor(pool, depth=pool.depth)
    log.info(
        "FRT worker processes started",
        extra={"workers": workers, "seconds": round(time.perf_counter() - start, 3)},
    )
    return True


def refine_by_notch_cut(compute: Callable[[], Any], result: Any) -> Refinement | None:
    """The scheduler's refinement (``FRT_FRT_NOTCH_CUT``): an exact set that could have a notch is
    cut by each stage of the notch cut in turn once it is ready (``ExactTask.refinement``)."""
    task = compute.refinement(result) if isinstance(compute, ExactTask) else None
    return None if task is None else Refinement(task, stage=task.stage)
