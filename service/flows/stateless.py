"""The stateless FRT (``POST /v1/frt``): a state and control bounds (or a prediction and beta) in,
contours and/or a collision answer out. Results are cached by their inputs like agents' sets.

The answer comes from the first exact set of its inputs: a set that may turn round is refined by
the notch cut in the background (``service.runtime.scheduler``) after it is answered, so a first
request answers from the uncut set, which contains the cut one, and says so
(``refinement_stage`` 0, ``refinement`` "pending"); the same request later answers from the
refined set once it has landed.

With ``map_id`` the answering set is cut to the map's drivable area while the state is on it
(``service.flows.road``), and the answer lists the assumption in ``assumptions``."""

from __future__ import annotations

import numpy as np
from starlette.concurrency import run_in_threadpool

from reach.agent_classes import DEFAULT_CLASS, agent_class
from reach.frames import Pose
from service.flows.agent_config import AgentConfig
from service.flows.checks import answer, wait_budget_s
from service.flows.contours import build
from service.flows.next_state import check_ranges, class_limits, mode_bounds, observed_prediction
from service.flows.road import map_entry, stateless_cut
from service.runtime.jobs import FRTJob
from service.runtime.services import Services
from service.wire.errors import FieldError
from service.wire.limits import check_slices, check_trajectory
from service.wire.schemas import ContourQuery, ControlBoundsOut, FRTRequest, FRTResponse


def request_bounds(services: Services, request: FRTRequest) -> np.ndarray:
    settings = services.settings
    if request.control_bounds is not None and request.prediction is not None:
        raise FieldError("prediction", "give either control_bounds or prediction, not both")
    if request.control_bounds is not None:
        for name in (
            "beta",
            "gamma",
            "bounds_fit",
            "bounds_rule",
            "rescue_onset",
        ):  # they shape bounds from a prediction only
            if getattr(request, name) is not None:
                raise FieldError(name, "applies to a prediction; control_bounds are used as given")
        return np.array(request.control_bounds.as_list(), dtype=np.float64)
    if request.prediction is None:
        raise FieldError("control_bounds", "give control_bounds, or a prediction and beta")
    if request.beta is None:
        raise FieldError("beta", "required with a prediction")
    prediction = observed_prediction(request.prediction, settings)
    shaping = {
        "gamma": request.gamma,
        "bounds_fit": request.bounds_fit,
        "bounds_rule": request.bounds_rule,
        "rescue_onset": request.rescue_onset,
    }
    config = AgentConfig.of(settings, shaping)
    limits = class_limits(agent_class(DEFAULT_CLASS), settings)
    return np.array(mode_bounds(prediction, 0, request.beta, config, settings, limits))


async def stateless_frt(services: Services, request: FRTRequest, arrival: float) -> FRTResponse:
    settings = services.settings
    engine = services.require_engine()
    horizon = services.horizon_s()
    bounds = request_bounds(services, request)
    field = "prediction" if request.control_bounds is None else "control_bounds"
    check_ranges(engine, agent_class(DEFAULT_CLASS), request.state.speed, bounds, field)
    query = request.contours
    if query is None and request.trajectory is None:
        query = ContourQuery()
    if query is not None:
        check_slices("contours.slices", query.slices, horizon, settings)
    check_trajectory("trajectory", request.trajectory, settings)
    road = map_entry(services, request.map_id)
    configured = settings.assumptions if request.assumptions is None else tuple(request.assumptions)
    radius = (
        request.collision_radius
        if request.collision_radius is not None
        else settings.collision_radius
    )

    state = request.state
    job = FRTJob.make("", 0, Pose(state.x, state.y, state.heading), state.speed, bounds)
    if request.deadline_ms is not None:
        wait_s = wait_budget_s(arrival, request.deadline_ms, settings)
    else:
        wait_s = settings.exact_timeout_s
    exact = await services.exact_within(job, wait_s)
    t_origin = request.timestamp if request.mode == "time_indexed" else None

    def compute() -> FRTResponse:
        frt = exact if exact is not None else services.conservative(job)
        frt, assumptions = stateless_cut(services, road, job, frt, state, configured)
        return FRTResponse(
            control_bounds=ControlBoundsOut.from_list(bounds.tolist()),
            beta=request.beta if request.control_bounds is None else None,
            horizon_s=horizon,
            collision_radius=radius,
            conservative=exact is None,
            refinement_stage=services.refinement_stage(exact),
            refinement=services.refinement_state(exact, job.key),
            contours=None if query is None else build(frt, query, radius, request.timestamp),
            collision=None
            if request.trajectory is None
            else answer(frt, request.trajectory, radius, t_origin),
            assumptions=assumptions,
        )

    return await run_in_threadpool(compute)
