"""Request and response models of every endpoint in API.md (pydantic v2).

Requests forbid unknown fields and non-finite numbers, so a typo or a NaN is a 422 that names the
field. Array lengths have hard caps here (they bound parsing and show in the OpenAPI schema); the
tighter limits of the server settings (``max_prediction_steps``, ``max_trajectory_points``,
``max_agents_per_check``, ``max_slices``) are enforced by :mod:`service.wire.limits`.
"""

from __future__ import annotations

import base64
from collections.abc import Sequence
from typing import Annotated, Any, Literal, NotRequired

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Discriminator,
    Field,
    PlainSerializer,
    PlainValidator,
    Tag,
    WithJsonSchema,
    computed_field,
    model_serializer,
    model_validator,
)
from typing_extensions import TypedDict

from reach.constraints import DEFAULT_PIECES, DEFAULT_SIDES, PIECES_RANGE, SIDES_RANGE
from reach.contract import BOUND_COLUMNS
from service.wire.binary64 import first_beyond, read_binary64

#: Hard caps on array lengths (the settings may only lower them).
PREDICTION_STEPS_CAP = 4096
TRAJECTORY_POINTS_CAP = 100_000
#: Trajectories one batch check may carry at most (``FRT_MAX_TRAJECTORIES`` is the tighter limit).
TRAJECTORIES_CAP = 4096
AGENTS_PER_CHECK_CAP = 10_000
#: Hard cap of agents in one frame (``FRT_MAX_AGENTS_PER_FRAME`` is the tighter limit).
AGENTS_PER_FRAME_CAP = 10_000
SLICES_CAP = 256
#: Modes of a multi-modal prediction parsed at most (the service allows ``MAX_MODES``).
MODES_CAP = 256
MAX_MODES = 32

#: Sanity bounds on magnitudes (metres, seconds, radians); finer ranges come from the model card.
COORD_MAX = 1e7
TIME_MAX = 1e12
ANGLE_MAX = 1e4
SPEED_MAX = 1e3
CONTROL_MAX = 1e3

AGENT_ID_PATTERN = r"^[A-Za-z0-9_.:\-]{1,128}$"
AgentId = Annotated[str, Field(pattern=AGENT_ID_PATTERN, description="1-128 of [A-Za-z0-9_.:-]")]
Coord = Annotated[float, Field(ge=-COORD_MAX, le=COORD_MAX)]
Time = Annotated[float, Field(ge=-TIME_MAX, le=TIME_MAX)]
Control = Annotated[float, Field(ge=-CONTROL_MAX, le=CONTROL_MAX)]
Vec2 = Annotated[list[Control], Field(min_length=2, max_length=2)]
Mat2 = Annotated[
    list[Annotated[list[float], Field(min_length=2, max_length=2)]],
    Field(min_length=2, max_length=2),
]
Radius = Annotated[float, Field(ge=0.0, le=100.0, description="metres")]
Mode = Literal["tube", "time_indexed"]
BoundsFit = Literal["envelope", "endpoints"]
BoundsRuleName = Literal["paper", "uniform_mixture", "mass_ramp"]
Part = Literal["K", "C"]
#: A GeoJSON geometry object (``Polygon`` or ``MultiPolygon``) in the world frame.
GeoJSON = dict[str, Any]


class Request(BaseModel):
    """A request body: unknown fields, non-finite numbers and numbers sent as strings or booleans
    are errors that name the field (strict: "1" and true are not silently read as 1.0)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True)


class Response(BaseModel):
    model_config = ConfigDict(extra="forbid")


# ----------------------------------------------------------------------------------- shared parts


class HumanState(Request):
    """The human's state in the world frame."""

    x: Coord
    y: Coord
    heading: float = Field(ge=-ANGLE_MAX, le=ANGLE_MAX, description="radians from +x, CCW")
    speed: float = Field(ge=0.0, le=SPEED_MAX, description="m/s, never negative")


class ObservedAction(Request):
    steering_rate: Control
    acceleration: Control


class Prediction(Request):
    """A predictor's Gaussian over the human's controls, one step per ``dt``."""

    dt: float = Field(gt=0.0, le=60.0, description="seconds between steps")
    mean: list[Vec2] = Field(min_length=1, max_length=PREDICTION_STEPS_CAP)
    cov: list[Mat2] = Field(min_length=1, max_length=PREDICTION_STEPS_CAP)


class PredictionMode(Request):
    """One mode of a multi-modal prediction: its weight and its Gaussian over the controls."""

    weight: float = Field(gt=0.0, description="positive; the modes' weights are normalised")
    mean: list[Vec2] = Field(min_length=1, max_length=PREDICTION_STEPS_CAP)
    cov: list[Mat2] = Field(min_length=1, max_length=PREDICTION_STEPS_CAP)


class ObservationPrediction(Request):
    """An observation's prediction: one Gaussian (``mean``, ``cov``) or a mixture (``modes``),
    one step per ``dt``. One mode means the single-Gaussian form."""

    dt: float = Field(gt=0.0, le=60.0, description="seconds between steps")
    mean: list[Vec2] | None = Field(None, min_length=1, max_length=PREDICTION_STEPS_CAP)
    cov: list[Mat2] | None = Field(None, min_length=1, max_length=PREDICTION_STEPS_CAP)
    modes: list[PredictionMode] | None = Field(
        None,
        min_length=1,
        max_length=MODES_CAP,
        description=f"at most {MAX_MODES}; each with the same dt and step layout",
    )

    @model_validator(mode="after")
    def _one_form(self) -> ObservationPrediction:
        if self.modes is not None:
            if self.mean is not None or self.cov is not None:
                raise ValueError("give either mean and cov, or modes, not both")
        elif self.mean is None or self.cov is None:
            raise ValueError("give mean and cov, or modes")
        return self


AgentClassName = Literal["car", "cyclist", "pedestrian"]
#: The map assumptions (docs/maps.md).
Assumption = Literal["drivable_area", "reachable_lanes", "speed_limit"]


class AgentConfig(Request):
    """Per-agent settings; omitted fields keep the agent's (or the server's) values."""

    beta_low: float | None = Field(None, gt=0.0, lt=1.0)
    gamma: float | None = Field(None, gt=0.0, lt=1.0)
    epsilon: float | None = Field(None, ge=0.0, lt=1.0)
    collision_radius: Radius | None = None
    bounds_fit: BoundsFit | None = None
    bounds_rule: BoundsRuleName | None = Field(
        None,
        description="how confidence widens the bounds (docs/confidence.md): 'paper' (covariance / "
        "beta, trimmed to mass gamma), 'uniform_mixture' (the tempered prediction mixed with a "
        "uniform over the class's limits, weighted by 1 - beta) or 'mass_ramp'",
    )
    rescue_onset: float | None = Field(
        None,
        ge=0.0,
        lt=1.0,
        description="the rule widens beyond the paper's only where 1 - beta exceeds this",
    )
    mode_mass: float | None = Field(
        None, gt=0.0, le=1.0, description="share of the mode posterior the served set holds"
    )
    mode_floor: float | None = Field(
        None, ge=0.0, lt=1.0, description="a mode above this posterior is never dropped"
    )
    coverage_target: float | None = Field(
        None,
        gt=0.0,
        lt=1.0,
        description="adaptive gamma: the long-run share of audited positions inside C to hold "
        "(docs/coverage.md); gamma then starts at the configured value and adapts",
    )
    coverage_step: float | None = Field(
        None, gt=0.0, le=1.0, description="the adaptive rule's step (eta)"
    )
    assumptions: list[Assumption] | None = Field(
        None,
        max_length=3,
        description="the map assumptions to answer under where the agent names a map (default: "
        "the server's FRT_ASSUMPTIONS); its class keeps those that apply to it: a car "
        "drivable_area, reachable_lanes and speed_limit, a cyclist drivable_area, a pedestrian none "
        "(docs/maps.md); [] for none",
    )


class EffectiveConfig(Response):
    beta_low: float
    beta_high: float
    gamma: float = Field(description="the configured gamma (adaptive gamma starts here)")
    epsilon: float
    collision_radius: float
    bounds_fit: str
    bounds_rule: str = Field(description="the confidence-to-bounds rule that builds the sets")
    rescue_onset: float
    coverage_target: float | None = Field(None, description="adaptive gamma's target; null: off")
    coverage_step: float
    assumptions: list[str] = Field(
        description="the configured map assumptions (before the agent's class and relaxation)"
    )


class LastMissOut(Response):
    """The worst audited position of the latest observation that left an earlier set's K."""

    timestamp: float = Field(description="the observation's time")
    frt_version: int = Field(description="the earlier version it left")
    t_rel_s: float = Field(description="seconds after that version's observation")
    distance_outside_k_m: float = Field(description="distance from K at that time (> 0)")
    distance_outside_c_m: float | None = Field(
        description="distance from C = K + R_col (> 0); null if the position was inside C"
    )
    source: Literal["exact", "conservative"] = Field(description="the set scored")


class AuditOut(Response):
    """The coverage audit of one agent (docs/coverage.md): its observed positions scored against
    the sets served earlier for it, one per earlier version whose horizon covers the position."""

    audited: int = Field(description="audited positions (position, earlier version) pairs")
    missed_k: int = Field(description="of them, outside K at that time")
    missed_c: int = Field(description="of them, outside C = K + R_col")
    exact: int = Field(description="of them, scored against the exact set (else conservative)")
    coverage_k: float | None = Field(description="1 - missed_k / audited; null before any")
    coverage_c: float | None = Field(description="1 - missed_c / audited; null before any")
    last_miss: LastMissOut | None = None
    assumption_misses: dict[str, int] = Field(
        default_factory=dict,
        description="per map assumption, the audited positions inside the uncut K but off the "
        "assumption's region, which the version's cut set missed (docs/maps.md); {} if none",
    )
    gamma_state: float | None = Field(
        None, description="adaptive gamma's running state (may exceed the gamma served); null: off"
    )


class ControlBoundsIn(Request):
    """Start and end control bounds, linearly interpolated over the horizon (model contract order)."""

    u1_min_start: Control
    u2_min_start: Control
    u1_min_end: Control
    u2_min_end: Control
    u1_max_start: Control
    u2_max_start: Control
    u1_max_end: Control
    u2_max_end: Control

    @model_validator(mode="after")
    def _ordered(self) -> ControlBoundsIn:
        for dim in ("u1", "u2"):
            for end in ("start", "end"):
                lo, hi = getattr(self, f"{dim}_min_{end}"), getattr(self, f"{dim}_max_{end}")
                if lo > hi:
                    raise ValueError(f"{dim}_min_{end} ({lo}) is above {dim}_max_{end} ({hi})")
        return self

    def as_list(self) -> list[float]:
        return [float(getattr(self, name)) for name in BOUND_COLUMNS]


class ControlBoundsOut(Response):
    u1_min_start: float
    u2_min_start: float
    u1_min_end: float
    u2_min_end: float
    u1_max_start: float
    u2_max_start: float
    u1_max_end: float
    u2_max_end: float

    @staticmethod
    def fields_of(values: Sequence[float]) -> dict[str, float]:
        """The eight bounds in contract order (``reach.contract.BOUND_COLUMNS``) as this model's
        fields, floats."""
        return dict(zip(BOUND_COLUMNS, map(float, values), strict=True))

    @classmethod
    def from_list(cls, values: Sequence[float]) -> ControlBoundsOut:
        """The model of :meth:`fields_of`."""
        return cls.model_construct(**cls.fields_of(values))


class BeliefOut(Response):
    """Probability of each hypothesis (or, as ``hypotheses``, the two beta values)."""

    beta_low: float
    beta_high: float

    @staticmethod
    def fields_of(values: Sequence[float]) -> dict[str, float]:
        """A value per hypothesis, ascending in beta, as this model's fields (API.md keys them
        by the lowest and the highest)."""
        return {"beta_low": float(values[0]), "beta_high": float(values[-1])}


Heading = Annotated[float, Field(ge=-ANGLE_MAX, le=ANGLE_MAX, description="radians from +x, CCW")]


class TrajectoryPoint(Request):
    t: Time = Field(description="seconds, on the observations' clock")
    x: Coord
    y: Coord
    heading: Heading | None = Field(None, description="the ego's heading; needed with a footprint")


Trajectory = Annotated[list[TrajectoryPoint], Field(min_length=1, max_length=TRAJECTORY_POINTS_CAP)]


class TrajectoryColumns(Request):
    """One trajectory as columns (the same points as a list of ``{t, x, y, heading}``, parsed
    several times faster: what the SDK sends)."""

    t: list[Time] = Field(min_length=1, max_length=TRAJECTORY_POINTS_CAP)
    x: list[Coord] = Field(min_length=1, max_length=TRAJECTORY_POINTS_CAP)
    y: list[Coord] = Field(min_length=1, max_length=TRAJECTORY_POINTS_CAP)
    heading: list[Heading] | None = Field(None, max_length=TRAJECTORY_POINTS_CAP)

    @model_validator(mode="after")
    def _same_lengths(self) -> TrajectoryColumns:
        lengths = {len(self.t), len(self.x), len(self.y)}
        if self.heading is not None:
            lengths.add(len(self.heading))
        if len(lengths) != 1:
            raise ValueError("t, x, y and heading need one entry per point each")
        return self


def _trajectory_form(value: Any) -> str:
    return "columns" if isinstance(value, dict | TrajectoryColumns) else "points"


#: A trajectory of a batch: a list of points or its columns (errors say which form was read).
BatchTrajectory = Annotated[
    Annotated[Trajectory, Tag("points")] | Annotated[TrajectoryColumns, Tag("columns")],
    Discriminator(_trajectory_form),
]


def _binary64_column(limit: float) -> Any:
    """A column of numbers sent as base64 of little-endian IEEE 754 binary64s (8 bytes a number),
    read into a float64 array: each finite and within +-``limit``."""

    def read(value: Any) -> np.ndarray:
        if not isinstance(value, str):
            raise ValueError("expected a base64 string of little-endian float64s")
        numbers = read_binary64(value)
        if numbers is None:
            raise ValueError(
                "not base64 (RFC 4648, padded, nothing else) of a whole number of 8-byte floats"
            )
        bad = first_beyond(numbers, limit)
        if bad >= 0:
            raise ValueError(f"number {bad} is not finite or beyond +-{limit:g}")
        return numbers

    def write(numbers: np.ndarray) -> str:
        return base64.b64encode(np.asarray(numbers, dtype="<f8").tobytes()).decode("ascii")

    return Annotated[
        Any,
        PlainValidator(read),
        PlainSerializer(write, return_type=str),
        WithJsonSchema(
            {
                "type": "string",
                "contentEncoding": "base64",
                "description": f"little-endian float64s, each finite and within +-{limit:g}",
            }
        ),
    ]


class PackedTrajectories(Request):
    """A batch of trajectories as flat columns, each column the points' numbers in order as
    base64 of little-endian IEEE 754 binary64s: trajectory k is the ``lengths[k]`` points after
    those of the trajectories before it. Read without a JSON number per point: what the SDK
    sends."""

    lengths: list[Annotated[int, Field(ge=1, le=TRAJECTORY_POINTS_CAP)]] = Field(
        min_length=1, max_length=TRAJECTORIES_CAP, description="each trajectory's points"
    )
    t: _binary64_column(TIME_MAX) = Field(description="seconds, on the observations' clock")  # type: ignore[valid-type]
    x: _binary64_column(COORD_MAX)  # type: ignore[valid-type]
    y: _binary64_column(COORD_MAX)  # type: ignore[valid-type]
    heading: _binary64_column(ANGLE_MAX) | None = Field(  # type: ignore[valid-type]
        None, description="the ego's heading at every point; needed with a footprint"
    )

    @model_validator(mode="after")
    def _one_number_per_point(self) -> PackedTrajectories:
        total = sum(self.lengths)
        for key in ("t", "x", "y", "heading"):
            column = getattr(self, key)
            if column is not None and len(column) != total:
                raise ValueError(f"{key} holds {len(column)} numbers; the lengths sum to {total}")
        return self


class Footprint(Request):
    """The ego's box, along the heading of each trajectory point."""

    length: float = Field(gt=0.0, le=50.0, description="metres, along the heading")
    width: float = Field(gt=0.0, le=20.0, description="metres, across it")
    rear_axle_to_center: float = Field(
        0.0,
        ge=-25.0,
        le=25.0,
        description="how far the box's centre lies ahead of the point along the heading (0: the "
        "box is centred on the point)",
    )


Verdict = Literal["exact", "decision_exact", "conservative"]


def answer_verdict(conservative: bool, collision: bool) -> Verdict:
    """How good a per-agent answer is: a set containing the exact one that a trajectory clears
    is cleared by the exact set too (API.md, "Frames": ``verdict``)."""
    if not conservative:
        return "exact"
    return "conservative" if collision else "decision_exact"


class CollisionAnswer(Response):
    collision: bool
    first_collision_index: int | None
    first_collision_time: float | None
    clearance: list[float] = Field(
        description="distance to K minus R_col per point; < 0 inside C (a conservative answer "
        "measures to the set that contains K, and inside it may state less than the full depth)"
    )


# ------------------------------------------------------------------------------------- agents


class ObservationRequest(Request):
    timestamp: Time
    state: HumanState
    observed_action: ObservedAction | None = Field(
        None, description="the action taken since the previous observation; null on the first"
    )
    prediction: ObservationPrediction
    config: AgentConfig | None = None
    agent_class: AgentClassName | None = Field(
        None, description="car (default), cyclist or pedestrian; fixed for an agent once set"
    )
    map_id: AgentId | None = Field(
        None,
        description="a registered map (PUT /v1/maps/{map_id}) the agent's sets are cut by under "
        "its assumptions (config.assumptions), kept for the agent until another is named; "
        "unknown: a 422 naming map_id (docs/maps.md)",
    )


class ModeOut(Response):
    """One mode of an agent's multi-modal prediction, in the order given."""

    weight: float = Field(description="the predictor's weight, normalised")
    posterior: float = Field(description="P(mode | observed actions), the joint belief's marginal")
    beta: float = Field(description="this mode's confidence: E[beta | mode]")
    in_set: bool = Field(description="whether the served FRT includes this mode's tube")
    control_bounds: ControlBoundsOut | None = Field(
        None, description="the bounds of this mode's tube, if in the set"
    )


class _DropsUnsetModes(Response):
    """A response whose ``modes`` and ``mode_mass`` appear only for a multi-modal agent."""

    modes: list[ModeOut] | None = None
    mode_mass: float | None = Field(
        None, description="the share of the mode posterior the served set's modes hold at least"
    )

    @model_serializer(mode="wrap")
    def _drop_unset_modes(self, handler: Any) -> dict[str, Any]:
        data = handler(self)
        if self.modes is None:
            data.pop("modes", None)
            data.pop("mode_mass", None)
        return data  # type: ignore[no-any-return]


class ObservationResponse(_DropsUnsetModes):
    agent_id: str
    timestamp: float
    beta: float
    belief: BeliefOut
    control_bounds: ControlBoundsOut
    frt_version: int
    action_scored: bool = Field(description="whether observed_action updated the belief")
    frt_ready: bool = Field(
        False, description="whether the exact FRT of this version is computed (see wait_frt_ms)"
    )


# -------------------------------------------------------------------------------------- frames


class FrameRequest(Request):
    """One frame of many agents (API.md, "Frames"): each entry is the observation body without
    ``timestamp`` plus ``agent_id``, validated on its own, so one bad agent is rejected by index
    and field while the others are applied."""

    timestamp: Time
    agents: list[Any] = Field(
        max_length=AGENTS_PER_FRAME_CAP,
        description="per agent: agent_id and the observation body's fields but timestamp",
        # Objects; an entry that is not one is rejected on its own (service.flows.frames).
        json_schema_extra={"items": {"type": "object"}},
    )


class FrameError(Response):
    status: int = Field(description="the HTTP status the agent's own observation would answer")
    detail: str
    field: str | None = Field(description="dotted, from the frame: agents.3.prediction.cov.2")


class FrameRejection(Response):
    """An agent of the frame that was not applied: nothing of it changed."""

    agent_id: str | None = Field(description="the entry's agent_id, if it has a valid one")
    index: int = Field(description="the entry's place in the frame's agents")
    error: FrameError


class FrameResponse(Response):
    timestamp: float
    applied: int = Field(description="agents whose observation was applied")
    rejected: int = Field(description="agents rejected (see their entries)")
    results: list[ObservationResponse | FrameRejection] = Field(
        description="one per agent, in the frame's order"
    )


class RelaxedAssumptionOut(Response):
    """A map assumption dropped for an agent that was observed breaking it."""

    assumption: str
    until: float = Field(
        description="on the agent's clock: the first observation at or after it tests the "
        "assumption again"
    )


class AgentResponse(_DropsUnsetModes):
    agent_id: str
    timestamp: float
    state: dict[str, float] = Field(description="pose and speed at the last observation")
    beta: float
    belief: BeliefOut
    hypotheses: BeliefOut = Field(description="the beta value of each hypothesis")
    control_bounds: ControlBoundsOut
    frt_version: int
    frt_ready: bool = Field(description="whether the exact FRT of this version is computed")
    frt_refinement: Literal["not_needed", "pending", "done", "failed"] | None = Field(
        None,
        description="once the exact FRT is ready: whether it is being tightened in the background "
        "(an agent that may turn round: its set cut to the speed-coupled partition, "
        "FRT_FRT_NOTCH_CUT, in stages, quick then fine), and whether that is done (no stage to "
        "come: the last served, or the fine one skipped because it would have landed after the "
        "agent's next observation; frt_refinement_stage says which), or failed (the served set "
        "then stays the one before, which contains the cut one); null before",
    )
    frt_refinement_stage: int | None = Field(
        None,
        description="once the exact FRT is ready: how many stages of the notch cut the served set "
        "has had (0: uncut; the last stage means frt_refinement is done); null before",
    )
    config: EffectiveConfig
    agent_class: str = Field("car", description="car, cyclist or pedestrian")
    gamma_effective: float = Field(
        description="the gamma the current version's sets are built with: the configured one, "
        "or adaptive gamma's (config.coverage_target)"
    )
    audit: AuditOut | None = Field(
        None, description="the coverage audit; null with the audit off (FRT_AUDIT=0)"
    )
    map_id: str | None = Field(None, description="the map the agent named; null: none")
    assumptions: list[str] = Field(
        default_factory=list,
        description="the map assumptions the agent's current version is answered under (checks "
        "and contours list them); empty without a map (docs/maps.md)",
    )
    relaxed_assumptions: list[RelaxedAssumptionOut] = Field(
        default_factory=list,
        description="assumptions dropped for the agent after it was observed breaking them, "
        "each until a time on its clock (FRT_ASSUMPTION_RELAX_S after the breach)",
    )


class DeleteResponse(Response):
    agent_id: str
    deleted: bool


# ---------------------------------------------------------------------------- collision checks


class CollisionCheckRequest(Request):
    """A check of one ``trajectory`` or of a batch of ``trajectories`` (exactly one of the two)."""

    trajectory: Trajectory | None = None
    trajectories: list[BatchTrajectory] | None = Field(
        None,
        min_length=1,
        max_length=TRAJECTORIES_CAP,
        description="a batch: each answered on its own, in ``trajectories`` of the answer",
    )
    packed_trajectories: PackedTrajectories | None = Field(
        None,
        description="instead of ``trajectories``: the same batch as packed binary columns, "
        "answered in ``trajectories`` of the answer",
    )
    include_clearance: bool = Field(
        False, description="with a batch: each trajectory's clearance per point too"
    )
    answer_columns: bool = Field(
        False,
        description="with a batch: its answers as columns (``trajectory_columns`` of the answer, "
        "one list per field) instead of an entry per trajectory (``trajectories``)",
    )
    footprint: Footprint | None = Field(
        None,
        description="check the ego's box at each point (covered by discs: a lower bound of its "
        "clearance) instead of the point",
    )
    mode: Mode = Field(
        "tube",
        description="tube: every point against the whole-horizon set; time_indexed: a point at "
        "time t against the tube up to t",
    )
    collision_radius: Radius | None = Field(None, description="default: the agent's R_col")
    deadline_ms: float | None = Field(
        None, gt=0.0, le=60_000.0, description="default: the server's; from the request's arrival"
    )

    @model_validator(mode="after")
    def _one_kind(self) -> CollisionCheckRequest:
        given = (self.trajectory, self.trajectories, self.packed_trajectories)
        if sum(part is not None for part in given) != 1:
            raise ValueError("give exactly one of trajectory, trajectories and packed_trajectories")
        return self


class TrajectoryAnswer(TypedDict):
    """One trajectory of a batch check against one agent."""

    collision: bool
    first_collision_index: int | None
    first_collision_time: float | None
    min_clearance: float
    clearance: NotRequired[list[float]]


class TrajectoryColumnsAnswer(TypedDict):
    """A batch check's answers against one agent as columns: item k of each list is trajectory
    k's :class:`TrajectoryAnswer` field."""

    collision: list[bool]
    first_collision_index: list[int | None]
    first_collision_time: list[float | None]
    min_clearance: list[float]
    clearance: NotRequired[list[list[float]]]


class CollisionCheckResponse(CollisionAnswer):
    agent_id: str
    mode: Mode
    collision_radius: float
    beta: float
    frt_version: int
    conservative: bool = Field(
        description="answered from a set containing the exact one: the outer bound while the exact "
        "set is late or there is no time left to measure it, or (time_indexed) tubes ending later "
        "than the points' own while those are not drawn in time"
    )
    horizon_end: float = Field(description="time after which the FRT says nothing")
    trajectories: list[TrajectoryAnswer] | None = Field(
        None,
        description="a batch check's answers, one per trajectory in order (then ``collision`` is "
        "any of them, ``clearance`` empty and the first collision null); absent otherwise",
    )
    trajectory_columns: TrajectoryColumnsAnswer | None = Field(
        None,
        description="a batch check's answers as columns, asked for by ``answer_columns`` "
        "(instead of ``trajectories``); absent otherwise",
    )
    collision_witnessed: bool = Field(
        False,
        description="a conservative collision whose verdict is certain: a position the human "
        "reaches under the bounds, no later than a point's time, lies within R_col of it, and "
        "the exact set holds every such position (its clearances and first collision stay the "
        "conservative set's); false otherwise",
    )
    assumptions: list[str] = Field(
        default_factory=list,
        description="the map assumptions the answer holds under: the agent's set cut to the "
        "road (docs/maps.md; a clear verdict measured on the uncut set, which contains the cut "
        "one, is the cut set's too and its clearance a lower bound of the cut set's); empty "
        "without a map, and for batch checks (answered from the uncut set)",
    )

    @model_serializer(mode="wrap")
    def _drop_unset_trajectories(self, handler: Any) -> dict[str, Any]:
        data = handler(self)
        for key in ("trajectories", "trajectory_columns"):
            if getattr(self, key) is None:
                data.pop(key, None)
        return data  # type: ignore[no-any-return]

    @computed_field(  # type: ignore[prop-decorator]
        description="exact: from the exact set; decision_exact: from a set containing the exact "
        "one and clear of it, so the exact set's verdict is the same (its clearance a lower bound "
        "of the exact one); conservative: from a set containing the exact one that the trajectory "
        "meets (the exact set may be clear)"
    )
    @property
    def verdict(self) -> Verdict:
        return answer_verdict(self.conservative, self.collision)


class MultiCollisionCheckRequest(CollisionCheckRequest):
    agent_ids: list[AgentId] | None = Field(
        None, max_length=AGENTS_PER_CHECK_CAP, description="null: every known agent"
    )


class MultiCollisionCheckResponse(Response):
    collision: bool = Field(description="any agent in collision")
    conservative: bool = Field(description="any answer conservative")
    results: list[CollisionCheckResponse]
    missing: list[str] = Field(description="requested agents that are unknown")


# ------------------------------------------------------------------------------------ contours


class ContourQuery(Request):
    slices: list[float] = Field(
        default_factory=list,
        max_length=SLICES_CAP,
        description="seconds after the observation; the set at each time: on the engine's 0.1 s "
        "grid the set at that instant, between two instants the set over the interval between "
        "them, which holds the set at t",
    )
    include: list[Part] = Field(default_factory=lambda: ["K", "C"], min_length=1, max_length=2)
    tube: bool = True


class ContourPair(Response):
    K: GeoJSON | None = None
    C: GeoJSON | None = None


class ContourSlice(ContourPair):
    t: float = Field(description="seconds after the observation")
    time: float = Field(description="on the observations' clock")


class Contours(Response):
    tube: ContourPair | None
    slices: list[ContourSlice]


class ContoursResponse(Contours):
    agent_id: str
    frt_version: int
    timestamp: float
    horizon_s: float
    collision_radius: float
    conservative: bool
    assumptions: list[str] = Field(
        default_factory=list,
        description="the map assumptions the contours' set was cut by (docs/maps.md); empty "
        "without a map",
    )
    uncut: Contours | None = Field(
        None,
        description="with include_uncut=true: the contours of the set before the cut (it "
        "contains the cut one), the same times and parts; null when no assumption cut the set. "
        "Absent without include_uncut",
    )

    # No return annotation: the OpenAPI schema keeps the model's fields.
    @model_serializer(mode="wrap")
    def _drop_unasked_uncut(self, handler: Any):
        data = handler(self)
        if "uncut" not in self.model_fields_set:
            data.pop("uncut", None)
        return data


# ---------------------------------------------------------------------------------- constraints


class ConstraintQuery(Request):
    """Which constraints: the times, and how many pieces of how many sides each at most."""

    slices: list[float] = Field(
        min_length=1,
        max_length=SLICES_CAP,
        description="seconds after the observation, each in [0, horizon]; the set at each time "
        "as the contours' slices have it",
    )
    max_sides: int = Field(
        DEFAULT_SIDES, ge=SIDES_RANGE[0], le=SIDES_RANGE[1], description="sides of a piece at most"
    )
    max_pieces: int = Field(
        DEFAULT_PIECES,
        ge=PIECES_RANGE[0],
        le=PIECES_RANGE[1],
        description="pieces per time at most",
    )
    collision_radius: Radius | None = Field(None, description="default: the agent's R_col")


class ConstraintPiece(Response):
    """The convex polygon {x : A x <= b} in the world frame."""

    A: list[list[float]] = Field(description="one unit outward normal [a_x, a_y] per side")
    b: list[float] = Field(description="one offset per side (metres)")
    vertices: list[list[float]] = Field(
        description="the corners [x, y], counter-clockwise, corner i where side i's line meets "
        "side i + 1's (for drawing: A x <= b is the piece)"
    )


class ConstraintSlice(Response):
    t: float = Field(description="seconds after the observation")
    time: float = Field(description="on the observations' clock")
    pieces: list[ConstraintPiece] = Field(description="their union contains C at this time")


class ConstraintsResponse(Response):
    agent_id: str
    frt_version: int
    timestamp: float
    horizon_s: float
    collision_radius: float
    conservative: bool
    assumptions: list[str] = Field(
        default_factory=list,
        description="the map assumptions the pieces hold under (docs/maps.md); none without a map",
    )
    max_sides: int
    max_pieces: int
    slices: list[ConstraintSlice]


# ------------------------------------------------------------------------------- stateless FRT


class FRTRequest(Request):
    """State plus either control bounds or a prediction and beta; contours and/or a check out.

    Exactly one of ``control_bounds`` and ``prediction`` (which needs ``beta``) must be given; the
    service checks that so the 422 can name the field.
    """

    timestamp: Time = Field(0.0, description="clock of the trajectory's t")
    state: HumanState
    control_bounds: ControlBoundsIn | None = None
    prediction: Prediction | None = None
    beta: float | None = Field(
        None, gt=0.0, le=1.0, description="confidence in the prediction: covariance / beta"
    )
    gamma: float | None = Field(None, gt=0.0, lt=1.0)
    bounds_fit: BoundsFit | None = None
    bounds_rule: BoundsRuleName | None = Field(
        None, description="the confidence-to-bounds rule (default: the server's)"
    )
    rescue_onset: float | None = Field(None, ge=0.0, lt=1.0)
    collision_radius: Radius | None = None
    contours: ContourQuery | None = Field(None, description="default: the tube when no trajectory")
    trajectory: Trajectory | None = None
    mode: Mode = "tube"
    deadline_ms: float | None = Field(
        None, gt=0.0, le=60_000.0, description="answer conservatively if the exact set is late"
    )
    map_id: AgentId | None = Field(
        None,
        description="a registered map (PUT /v1/maps/{map_id}): the car's set is cut by the "
        "assumptions its state keeps (docs/maps.md)",
    )
    assumptions: list[Assumption] | None = Field(
        None,
        max_length=3,
        description="with map_id: the map assumptions to answer under (default: the server's "
        "FRT_ASSUMPTIONS); those the state breaks are dropped",
    )


class FRTResponse(Response):
    control_bounds: ControlBoundsOut
    beta: float | None
    horizon_s: float
    collision_radius: float
    conservative: bool
    refinement_stage: int | None = Field(
        None,
        description="how many stages of the notch cut the set answered from has had (0: the "
        "uncut exact set, which contains the cut ones: a set that may turn round is answered "
        "uncut unless the same request came before and its refinement has landed since); null "
        "when the answer is conservative",
    )
    refinement: Literal["not_needed", "pending", "done", "failed"] | None = Field(
        None,
        description="as an agent's frt_refinement: whether a tighter set of the same inputs is "
        "being computed in the background (asking again may answer from it); null when the "
        "answer is conservative",
    )
    contours: Contours | None
    collision: CollisionAnswer | None
    assumptions: list[str] = Field(
        default_factory=list,
        description="the map assumptions the answering set was cut by ('drivable_area'); empty "
        "without a map, or for a state off the map's drivable area",
    )


# --------------------------------------------------------------------------------- model, health


class NetworkPart(Response):
    loaded: bool
    active: bool = Field(description="whether the network is evaluated when a set is built")
    reason: str


class ActiveParts(Response):
    """Which parts build the sets the service serves."""

    geometry: list[str] = Field(
        description="the certified geometry: 'outer_bound' always, 'notch_partition' when sets "
        "that may turn round are refined by the speed-coupled partition"
    )
    value_network: NetworkPart
    bounds_rule: str = Field(
        description="the server's confidence-to-bounds rule (agents may choose their own)"
    )


class ModelCardResponse(Response):
    name: str
    semantics: str
    delta: float
    horizon_s: float
    ranges: dict[str, list[float]]
    initial_set: dict[str, Any]
    card: dict[str, Any] = Field(description="the whole model card")
    active: ActiveParts


class Health(Response):
    status: str


class Readiness(Response):
    ready: bool
    model: str | None
    detail: str | None = None
    active: ActiveParts | None = None


# ------------------------------------------------------------------------------------------- maps


class MapArchive(BaseModel):
    """An Argoverse 2 map archive (``log_map_archive_*.json``): each collection an object from id
    to element. Validated by ``reach.road_map`` (a 422 names the field by its dotted path); this
    model documents the body."""

    model_config = ConfigDict(extra="forbid")

    drivable_areas: dict[str, dict[str, Any]] = Field(
        description="id -> {id, area_boundary: [{x, y, z}, ...]}: the polygons a car may drive on"
    )
    lane_segments: dict[str, dict[str, Any]] = Field(
        default_factory=dict,
        description="id -> {id, lane_type, is_intersection, left_lane_boundary, "
        "right_lane_boundary, centerline, successors, predecessors, left_neighbor_id, "
        "right_neighbor_id, ...}",
    )
    pedestrian_crossings: dict[str, dict[str, Any]] = Field(
        default_factory=dict, description="id -> {id, edge1, edge2}: two polylines each"
    )


class MapResponse(Response):
    map_id: str
    source: Literal["file", "api"] = Field(description="FRT_MAP at start-up, or PUT")
    format: Literal["argoverse2", "lanelet2"] = Field(
        description="an Argoverse 2 map archive (JSON) or a Lanelet2 OSM file (XML)"
    )
    size_bytes: int
    drivable_areas: int
    lane_segments: int
    speed_limited_lanes: int = Field(
        description="lanes whose speed limit the map gives (the speed_limit assumption's; none "
        "in an Argoverse 2 archive)"
    )
    pedestrian_crossings: int
    extent: list[float] = Field(
        description="[x_min, y_min, x_max, y_max] of every element: outside it nothing is cut"
    )
    drivable_area_m2: float
    vertices: int = Field(description="vertices of the drivable area's union")
    margin_m: float = Field(description="the drivable area is grown by this before it cuts")
    replaced: bool | None = Field(
        None, description="PUT: whether the id held a map before (null on GET)"
    )


class MapDeleteResponse(Response):
    map_id: str
    deleted: bool


class MapGeoJSONResponse(Response):
    """A map's geometry within a box, for drawing: a GeoJSON FeatureCollection in the map's
    (world) frame, with the box and the simplification it was drawn at as foreign members."""

    type: Literal["FeatureCollection"] = "FeatureCollection"
    features: list[dict[str, Any]] = Field(
        description="GeoJSON Features: the drivable area D within the box (properties.kind "
        "drivable_area), each lane's area (kind lane) and centre line (kind centerline) with "
        "lane_id, lane_type, is_intersection"
    )
    map_id: str
    bbox: list[float] = Field(description="[x_min, y_min, x_max, y_max] the geometry is cut to")
    extent: list[float] = Field(description="the map's extent, as its summary has it")
    simplify_m: float = Field(
        description="the simplification tolerance used (metres): the one asked for, doubled "
        "while the answer held more vertices than the server's cap"
    )
    vertices: int = Field(description="vertices in the features")
