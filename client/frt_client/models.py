"""Typed responses of the service (pydantic v2), mirroring ``/openapi.json`` without importing it.

Responses ignore fields they do not know, so a newer service does not break an older SDK. Units are
SI throughout: metres, seconds, radians, m/s, m/s². GeoJSON geometries are plain dicts
(``{"type": "Polygon", "coordinates": ...}``) in the caller's world frame.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

Mode = Literal["tube", "time_indexed"]
Part = Literal["K", "C"]
BoundsFit = Literal["envelope", "endpoints"]
BoundsRule = Literal["paper", "uniform_mixture", "mass_ramp"]
#: The map assumptions a set may be cut by (the service's docs/maps.md).
Assumption = Literal["drivable_area", "reachable_lanes", "speed_limit"]
#: A GeoJSON geometry object (``Polygon`` or ``MultiPolygon``) in the world frame.
GeoJSON = dict[str, Any]


class Response(BaseModel):
    """Base of every response: unknown fields are ignored, instances are read-only."""

    model_config = ConfigDict(extra="ignore", frozen=True)


class Belief(Response):
    """Probability of each hypothesis (or, in ``Agent.hypotheses``, the two β values)."""

    beta_low: float
    beta_high: float


class ControlBounds(Response):
    """Start and end control bounds, linearly interpolated over the horizon (model order)."""

    u1_min_start: float
    u2_min_start: float
    u1_min_end: float
    u2_min_end: float
    u1_max_start: float
    u2_max_start: float
    u1_max_end: float
    u2_max_end: float


class EffectiveConfig(Response):
    """The settings in force for one agent (its overrides, else the server's)."""

    beta_low: float
    beta_high: float
    gamma: float
    epsilon: float
    collision_radius: float
    bounds_fit: str
    #: The confidence-to-bounds rule building the agent's sets, and its onset.
    bounds_rule: str = "paper"
    rescue_onset: float = 0.0
    #: Adaptive gamma's target share of audited positions inside C (None: gamma fixed).
    coverage_target: float | None = None
    coverage_step: float | None = None
    #: The configured map assumptions (the agent's class keeps those that apply to it).
    assumptions: tuple[str, ...] = ()


class LastMiss(Response):
    """The worst audited position of the agent's latest observation that left an earlier set."""

    #: The observation's time, the earlier version it left, and how long after that version.
    timestamp: float
    frt_version: int
    t_rel_s: float
    #: Distance outside K at that time (> 0), and outside C (None if inside C).
    distance_outside_k_m: float
    distance_outside_c_m: float | None = None
    #: The set scored: "exact" or "conservative" (which contains the exact one).
    source: str


class Audit(Response):
    """The coverage audit of one agent: its observed positions against its earlier sets."""

    #: (position, earlier version covering its time) pairs scored, and how many left K, C.
    audited: int
    missed_k: int
    missed_c: int
    #: How many were scored against the exact set (else the conservative one).
    exact: int = 0
    coverage_k: float | None = None
    coverage_c: float | None = None
    last_miss: LastMiss | None = None
    #: Per map assumption, the positions inside the uncut K that its cut set missed.
    assumption_misses: dict[str, int] = Field(default_factory=dict)
    #: Adaptive gamma's running state (None without a coverage target).
    gamma_state: float | None = None


class AgentMode(Response):
    """One mode of a multi-modal agent, in the order given."""

    weight: float
    #: P(mode | observed actions).
    posterior: float
    #: This mode's confidence E[beta | mode].
    beta: float
    #: Whether the served FRT includes this mode's tube, and from which bounds.
    in_set: bool
    control_bounds: ControlBounds | None = None


class ObservationResult(Response):
    """Answer to :meth:`FRTClient.observe`."""

    agent_id: str
    timestamp: float
    beta: float
    belief: Belief
    control_bounds: ControlBounds
    frt_version: int
    action_scored: bool = False
    #: Whether the exact FRT of this version was computed when the answer left (``wait_frt_ms``).
    frt_ready: bool = False
    #: A multi-modal agent's modes (None for a single Gaussian) and the posterior share the
    #: served set's modes hold at least.
    modes: tuple[AgentMode, ...] | None = None
    mode_mass: float | None = None


class FrameError(Response):
    #: The HTTP status the agent's own observation would have answered.
    status: int
    detail: str
    #: Dotted, from the frame: ``agents.3.prediction.cov.2``.
    field: str | None = None


class FrameRejection(Response):
    """An agent of a frame that was not applied: nothing of it changed."""

    agent_id: str | None = None
    #: The entry's place in the frame.
    index: int
    error: FrameError


class FrameResult(Response):
    """Answer to :meth:`FRTClient.frame`: one result per agent, in the frame's order."""

    timestamp: float
    applied: int
    rejected: int
    results: list[ObservationResult | FrameRejection]

    def rejections(self) -> list[FrameRejection]:
        return [r for r in self.results if isinstance(r, FrameRejection)]


class RelaxedAssumption(Response):
    """A map assumption dropped for an agent observed breaking it, until a time on its clock."""

    assumption: str
    until: float


class Agent(Response):
    """Answer to :meth:`FRTClient.get_agent`: what the service holds for one human."""

    agent_id: str
    timestamp: float
    state: dict[str, float] = Field(default_factory=dict)
    beta: float
    belief: Belief
    hypotheses: Belief | None = None
    control_bounds: ControlBounds
    frt_version: int
    frt_ready: bool = False
    #: Once the exact FRT is ready: "pending" while the service tightens it in the background (an
    #: agent that may turn round; in stages, quick then fine), "done" when no stage is to come
    #: (the fine one is skipped if it would land after the agent's next observation), "failed"
    #: if one raised (the set before, which contains the cut one, stays), "not_needed" otherwise.
    frt_refinement: str | None = None
    #: How many stages of that tightening the served set has had (0: none yet).
    frt_refinement_stage: int | None = None
    config: EffectiveConfig | None = None
    agent_class: str = "car"
    modes: tuple[AgentMode, ...] | None = None
    mode_mass: float | None = None
    #: The gamma the current version's bounds are fitted with (adaptive with a coverage target).
    gamma_effective: float | None = None
    #: The coverage audit (None with the audit off).
    audit: Audit | None = None
    #: The map the agent named (None: none), the map assumptions its current version is answered
    #: under, and those dropped for it after it was observed breaking them.
    map_id: str | None = None
    assumptions: tuple[str, ...] = ()
    relaxed_assumptions: tuple[RelaxedAssumption, ...] = ()


class DeleteResult(Response):
    agent_id: str
    deleted: bool


class CollisionAnswer(Response):
    """Whether a trajectory enters the unsafe set C = K ⊕ R_col, and where."""

    collision: bool
    first_collision_index: int | None = None
    first_collision_time: float | None = None
    #: Distance to K minus R_col per trajectory point; negative inside C.
    clearance: list[float] = Field(default_factory=list)


class TrajectoryAnswer(Response):
    """One trajectory of a batch check (``trajectories=``) against one agent."""

    collision: bool
    first_collision_index: int | None = None
    first_collision_time: float | None = None
    #: The least of the trajectory's clearances (distance to K minus R_col; negative inside C).
    min_clearance: float
    #: Per point, with ``include_clearance=True``.
    clearance: list[float] | None = None


class CollisionCheck(CollisionAnswer):
    """Answer to :meth:`FRTClient.collision_check` for one agent."""

    agent_id: str
    mode: Mode
    collision_radius: float
    beta: float
    frt_version: int
    #: True when answered from a set containing the exact one (the exact set was not ready in time).
    conservative: bool
    #: Time after which the FRT says nothing.
    horizon_end: float | None = None
    #: "exact" (from the exact set), "decision_exact" (from a set containing it and clear of it:
    #: the exact set's verdict too) or "conservative" (that set is met; the exact one may be clear).
    verdict: Literal["exact", "decision_exact", "conservative"] | None = None
    #: A conservative collision whose verdict is certain: a position the human reaches lies
    #: within R_col of a point by its time, and the exact set holds it (False from a server
    #: that does not say).
    collision_witnessed: bool = False
    #: A batch check's answers, one per trajectory in order (then ``collision`` is any of them).
    trajectories: list[TrajectoryAnswer] | None = None
    #: The map assumptions the answer holds under (the agent's set cut to the road); empty
    #: without a map and for batch checks.
    assumptions: tuple[str, ...] = ()

    @model_validator(mode="before")
    @classmethod
    def _entries_from_columns(cls, data: Any) -> Any:
        """A batch answered as columns (``trajectory_columns``, what the SDK asks for) read as
        its entries, one :class:`TrajectoryAnswer` per trajectory."""
        if not isinstance(data, dict) or data.get("trajectory_columns") is None:
            return data
        columns = data["trajectory_columns"]
        keys = [key for key in _ANSWER_FIELDS if key in columns]
        rows = zip(*(columns[k] for k in keys), strict=True)
        entries = [dict(zip(keys, row, strict=True)) for row in rows]
        rest = {k: v for k, v in data.items() if k != "trajectory_columns"}
        return {**rest, "trajectories": entries}


#: The fields of a batch's answer per trajectory, as entries and as columns.
_ANSWER_FIELDS = (
    "collision",
    "first_collision_index",
    "first_collision_time",
    "min_clearance",
    "clearance",
)


class MultiCollisionCheck(Response):
    """Answer to :meth:`FRTClient.collision_check_many`."""

    collision: bool
    conservative: bool
    results: list[CollisionCheck]
    #: Requested agents the service does not know.
    missing: list[str] = Field(default_factory=list)

    def by_agent(self) -> dict[str, CollisionCheck]:
        """The per-agent results keyed by agent id."""
        return {r.agent_id: r for r in self.results}


class ContourPair(Response):
    K: GeoJSON | None = None
    C: GeoJSON | None = None


class ContourSlice(ContourPair):
    #: Seconds after the observation.
    t: float
    #: The same instant on the observations' clock.
    time: float | None = None


class ContourSet(Response):
    tube: ContourPair | None = None
    slices: list[ContourSlice] = Field(default_factory=list)


class AgentContours(ContourSet):
    """Answer to :meth:`FRTClient.contours`: K and C of one agent as GeoJSON."""

    agent_id: str
    frt_version: int
    timestamp: float
    horizon_s: float
    collision_radius: float
    conservative: bool
    #: The map assumptions the set drawn was cut by (empty without a map).
    assumptions: tuple[str, ...] = ()
    #: Asked for with ``include_uncut``: the same contours of the set before the map assumptions
    #: cut it (None where none cut it).
    uncut: ContourSet | None = None


class ConstraintPiece(Response):
    """One convex piece {x : A x <= b} in the world frame."""

    #: One unit outward normal ``[a_x, a_y]`` per side.
    A: list[list[float]]
    #: One offset per side (metres).
    b: list[float]
    #: The corners ``[x, y]``, counter-clockwise (for drawing: ``A x <= b`` is the piece).
    vertices: list[list[float]] = Field(default_factory=list)

    def contains(self, x: float, y: float, tolerance: float = 0.0) -> bool:
        """Whether (x, y) meets every side (within ``tolerance`` metres)."""
        return all(
            a[0] * x + a[1] * y <= b + tolerance for a, b in zip(self.A, self.b, strict=True)
        )


class ConstraintSlice(Response):
    #: Seconds after the observation.
    t: float
    #: The same instant on the observations' clock.
    time: float | None = None
    #: Convex pieces whose union contains C at this time.
    pieces: list[ConstraintPiece] = Field(default_factory=list)

    def contains(self, x: float, y: float, tolerance: float = 0.0) -> bool:
        """Whether (x, y) lies in some piece: False means it is outside C at this time."""
        return any(piece.contains(x, y, tolerance) for piece in self.pieces)


class AgentConstraints(Response):
    """Answer to :meth:`FRTClient.constraints`: per requested time, convex pieces in the world
    frame whose union contains C = K ⊕ R_col of one agent."""

    agent_id: str
    frt_version: int
    timestamp: float
    horizon_s: float
    collision_radius: float
    #: True when built from a set containing the exact one (the exact set was not ready in time).
    conservative: bool
    #: The map assumptions the pieces hold under (the agent's set cut to the road); empty without
    #: a map.
    assumptions: tuple[str, ...] = ()
    max_sides: int
    max_pieces: int
    slices: list[ConstraintSlice]


class FRTResult(Response):
    """Answer to the stateless :meth:`FRTClient.frt`."""

    control_bounds: ControlBounds
    beta: float | None = None
    horizon_s: float
    collision_radius: float
    conservative: bool
    contours: ContourSet | None = None
    collision: CollisionAnswer | None = None
    #: The map assumptions the answering set was cut by (with ``map_id``).
    assumptions: tuple[str, ...] = ()


class ModelCard(Response):
    """Answer to :meth:`FRTClient.model`: the served network's card."""

    name: str
    semantics: str
    delta: float
    horizon_s: float
    ranges: dict[str, list[float]] = Field(default_factory=dict)
    initial_set: dict[str, Any] = Field(default_factory=dict)
    #: The whole model card as the service has it.
    card: dict[str, Any] = Field(default_factory=dict)


class Health(Response):
    status: str


class Readiness(Response):
    ready: bool
    model: str | None = None
    detail: str | None = None
