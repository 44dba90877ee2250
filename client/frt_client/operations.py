"""The operations shared by a client and its stream, in a blocking and an async flavour.

:class:`Operations` (blocking) and :class:`AsyncOperations` have the same methods with the same
arguments; each builds a :class:`~frt_client.calls.Call` and hands it to ``send``, which the
HTTP clients and the WebSocket streams implement. Every method raises a subclass of
:class:`~frt_client.errors.FRTError` on failure.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any, TypeVar

from frt_client import calls
from frt_client.calls import Call
from frt_client.models import (
    Agent,
    AgentConstraints,
    AgentContours,
    CollisionCheck,
    DeleteResult,
    FrameResult,
    FRTResult,
    Mode,
    MultiCollisionCheck,
    ObservationResult,
    Response,
)

T = TypeVar("T", bound=Response)


class Operations:
    """The API's operations, blocking. Subclasses implement :meth:`send`."""

    def send(self, call: Call[T]) -> T:
        """Execute one call and return its typed result."""
        raise NotImplementedError

    # ------------------------------------------------------------------ agents
    def observe(
        self,
        agent_id: str,
        *,
        timestamp: float,
        state: Any,
        prediction: Any,
        observed_action: Any = None,
        config: Any = None,
        wait_frt_ms: float = 0.0,
        agent_class: str | None = None,
        map_id: str | None = None,
    ) -> ObservationResult:
        """Report a new observation of one human; never sent twice (see :mod:`frt_client.retry`).

        Args:
            agent_id: the caller's id of the human (1-128 of ``[A-Za-z0-9_.:-]``).
            timestamp: seconds on the caller's clock; must increase per agent (else 409).
            state: ``(x, y, heading, speed)``, a mapping, or :class:`~frt_client.HumanState`.
            prediction: ``{"dt", "mean": (S, 2), "cov": (S, 2, 2)}`` or
                :class:`~frt_client.Prediction`; arrays may be numpy. A multi-modal one:
                ``{"dt", "modes": [{"weight", "mean", "cov"}, ...]}`` (:mod:`frt_client.mixtures`).
            observed_action: ``(steering_rate, acceleration)`` taken since the previous
                observation, scored against the first step of the previous prediction;
                ``None`` on the first observation.
            config: per-agent settings (:class:`~frt_client.AgentConfig` or mapping), from now on.
            agent_class: ``"car"`` (the service's default), ``"cyclist"`` or ``"pedestrian"``;
                fixed for the agent once set (409 if changed).
            map_id: a map registered on the service (``PUT /v1/maps/{map_id}``): the agent's
                sets are cut to the road under its map assumptions (``config.assumptions``),
                the map kept for it until another is named (unknown: 422 naming ``map_id``).
            wait_frt_ms: answer once the new version's exact FRT is computed or this much time
                has passed (at most 10 000; ``frt_ready`` says which; HTTP only): the fresh set
                in one request instead of a following ``get_agent(wait_frt_ms=...)``.
        """
        return self.send(
            calls.observe(
                agent_id,
                timestamp=timestamp,
                state=state,
                prediction=prediction,
                observed_action=observed_action,
                config=config,
                wait_frt_ms=wait_frt_ms,
                agent_class=agent_class,
                map_id=map_id,
            )
        )

    def frame(self, *, timestamp: float, agents: Iterable[Any]) -> FrameResult:
        """Report one frame of many humans in one request (``POST /v1/frames``); never sent
        twice. ``agents``: per human a mapping with ``agent_id``, ``state``, ``prediction`` and
        optionally ``observed_action``, ``config``, ``agent_class``, ``map_id`` (as
        :meth:`observe`). A
        rejected human is answered by index and field (:meth:`FrameResult.rejections`); nothing
        of it changes and the others are applied."""
        return self.send(calls.frame(timestamp=timestamp, agents=agents))

    def get_agent(self, agent_id: str, *, wait_frt_ms: float = 0.0) -> Agent:
        """The agent's β, belief, control bounds, last timestamp, FRT version and config; with
        ``wait_frt_ms`` (at most 10 000; keep the client's timeout above it), answered once the
        exact FRT of its current version is ready or that time has passed (``frt_ready`` says
        which)."""
        return self.send(calls.get_agent(agent_id, wait_frt_ms))

    def delete_agent(self, agent_id: str) -> DeleteResult:
        """Forget the agent (404 if unknown)."""
        return self.send(calls.delete_agent(agent_id))

    # ------------------------------------------------------------------ checks
    def collision_check(
        self,
        agent_id: str,
        trajectory: Any = None,
        *,
        trajectories: Any = None,
        mode: Mode = "tube",
        collision_radius: float | None = None,
        deadline_ms: float | None = None,
        footprint: Any = None,
        include_clearance: bool = False,
    ) -> CollisionCheck:
        """Does the robot ``trajectory`` enter the agent's unsafe set C = K ⊕ R_col?

        Args:
            trajectory: ``(N, 3)`` rows ``(t, x, y)`` (t on the observations' clock), ``(N, 4)``
                rows ``(t, x, y, heading)``, or points.
            trajectories: instead of ``trajectory``, a batch of candidate trajectories (an
                ``(M, N, 3 or 4)`` array or a list of trajectories), each answered on its own in
                the answer's ``trajectories``.
            mode: ``"tube"`` (every point against the whole horizon) or ``"time_indexed"``.
            collision_radius: R_col in metres; default the agent's.
            deadline_ms: the service answers within it, conservatively if need be.
            footprint: the ego's box ``(length, width[, rear_axle_to_center])`` or a mapping,
                checked along each point's heading instead of the point (headings required).
            include_clearance: with ``trajectories``, each one's clearance per point too.
        """
        return self.send(
            calls.collision_check(
                agent_id,
                trajectory,
                trajectories=trajectories,
                options=calls.CheckOptions(
                    mode, collision_radius, deadline_ms, footprint, include_clearance
                ),
            )
        )

    def collision_check_many(
        self,
        trajectory: Any = None,
        agent_ids: Iterable[str] | None = None,
        *,
        trajectories: Any = None,
        mode: Mode = "tube",
        collision_radius: float | None = None,
        deadline_ms: float | None = None,
        footprint: Any = None,
        include_clearance: bool = False,
    ) -> MultiCollisionCheck:
        """The same check (see :meth:`collision_check`) against several agents in one call;
        ``agent_ids=None`` checks all."""
        return self.send(
            calls.collision_check_many(
                trajectory,
                agent_ids,
                trajectories=trajectories,
                options=calls.CheckOptions(
                    mode, collision_radius, deadline_ms, footprint, include_clearance
                ),
            )
        )

    # ------------------------------------------------------------------ sets
    def contours(
        self,
        agent_id: str,
        *,
        slices: Iterable[float] = (),
        include: Iterable[str] = ("K", "C"),
        tube: bool = True,
        collision_radius: float | None = None,
        include_uncut: bool = False,
    ) -> AgentContours:
        """GeoJSON contours of the agent's K and C: the whole-horizon tube and time slices.

        Args:
            slices: seconds after the last observation, each in ``[0, horizon]``.
            include: any of ``"K"`` (the FRT) and ``"C"`` (K inflated by R_col).
            tube: include the whole-horizon tube.
            include_uncut: also the same contours of the set before the agent's map
                assumptions cut it (``uncut``).
        """
        return self.send(
            calls.contours(
                agent_id,
                slices=slices,
                include=include,
                tube=tube,
                collision_radius=collision_radius,
                include_uncut=include_uncut,
            )
        )

    def constraints(
        self,
        agent_id: str,
        *,
        slices: Iterable[float],
        collision_radius: float | None = None,
        max_sides: int | None = None,
        max_pieces: int | None = None,
    ) -> AgentConstraints:
        """Per time, convex pieces ``{x : A x <= b}`` in the world frame whose union contains
        the agent's C = K ⊕ R_col at that time: constraints for a planner's MPC.

        Args:
            slices: seconds after the last observation, each in ``[0, horizon]``.
            collision_radius: R_col of C (default: the agent's).
            max_sides: sides of one piece at most (3 to 64; default 16).
            max_pieces: pieces of one time at most (1 to 16; default 4).
        """
        return self.send(
            calls.constraints(
                agent_id,
                slices=slices,
                collision_radius=collision_radius,
                max_sides=max_sides,
                max_pieces=max_pieces,
            )
        )

    def frt(
        self,
        state: Any,
        *,
        control_bounds: Any = None,
        prediction: Any = None,
        beta: float | None = None,
        gamma: float | None = None,
        bounds_fit: str | None = None,
        bounds_rule: str | None = None,
        rescue_onset: float | None = None,
        collision_radius: float | None = None,
        contours: dict[str, Any] | None = None,
        trajectory: Any = None,
        mode: Mode = "tube",
        deadline_ms: float | None = None,
        timestamp: float = 0.0,
    ) -> FRTResult:
        """The stateless FRT: give ``control_bounds`` (eight numbers or a mapping), or a
        ``prediction`` and ``beta``; get contours (``contours={"slices": [...], "include":
        [...], "tube": bool}``) and/or a check of ``trajectory``. No agent is kept."""
        return self.send(
            calls.frt(
                state,
                control_bounds=control_bounds,
                prediction=prediction,
                beta=beta,
                gamma=gamma,
                bounds_fit=bounds_fit,
                bounds_rule=bounds_rule,
                rescue_onset=rescue_onset,
                collision_radius=collision_radius,
                contours=contours,
                trajectory=trajectory,
                mode=mode,
                deadline_ms=deadline_ms,
                timestamp=timestamp,
            )
        )


class AsyncOperations:
    """The API's operations, as coroutines. Subclasses implement :meth:`send`."""

    async def send(self, call: Call[T]) -> T:
        """Execute one call and return its typed result."""
        raise NotImplementedError

    # ------------------------------------------------------------------ agents
    async def observe(
        self,
        agent_id: str,
        *,
        timestamp: float,
        state: Any,
        prediction: Any,
        observed_action: Any = None,
        config: Any = None,
        wait_frt_ms: float = 0.0,
        agent_class: str | None = None,
        map_id: str | None = None,
    ) -> ObservationResult:
        """Report a new observation of one human; never sent twice (see :mod:`frt_client.retry`).

        Args:
            agent_id: the caller's id of the human (1-128 of ``[A-Za-z0-9_.:-]``).
            timestamp: seconds on the caller's clock; must increase per agent (else 409).
            state: ``(x, y, heading, speed)``, a mapping, or :class:`~frt_client.HumanState`.
            prediction: ``{"dt", "mean": (S, 2), "cov": (S, 2, 2)}`` or
                :class:`~frt_client.Prediction`; arrays may be numpy. A multi-modal one:
                ``{"dt", "modes": [{"weight", "mean", "cov"}, ...]}`` (:mod:`frt_client.mixtures`).
            observed_action: ``(steering_rate, acceleration)`` taken since the previous
                observation, scored against the first step of the previous prediction;
                ``None`` on the first observation.
            config: per-agent settings (:class:`~frt_client.AgentConfig` or mapping), from now on.
            agent_class: ``"car"`` (the service's default), ``"cyclist"`` or ``"pedestrian"``;
                fixed for the agent once set (409 if changed).
            map_id: a map registered on the service (``PUT /v1/maps/{map_id}``): the agent's
                sets are cut to the road under its map assumptions (``config.assumptions``),
                the map kept for it until another is named (unknown: 422 naming ``map_id``).
            wait_frt_ms: answer once the new version's exact FRT is computed or this much time
                has passed (at most 10 000; ``frt_ready`` says which; HTTP only).
        """
        return await self.send(
            calls.observe(
                agent_id,
                timestamp=timestamp,
                state=state,
                prediction=prediction,
                observed_action=observed_action,
                config=config,
                wait_frt_ms=wait_frt_ms,
                agent_class=agent_class,
                map_id=map_id,
            )
        )

    async def frame(self, *, timestamp: float, agents: Iterable[Any]) -> FrameResult:
        """Report one frame of many humans in one request (see :meth:`Operations.frame`)."""
        return await self.send(calls.frame(timestamp=timestamp, agents=agents))

    async def get_agent(self, agent_id: str, *, wait_frt_ms: float = 0.0) -> Agent:
        """The agent's β, belief, control bounds, last timestamp, FRT version and config; with
        ``wait_frt_ms`` (at most 10 000; keep the client's timeout above it), answered once the
        exact FRT of its current version is ready or that time has passed (``frt_ready`` says
        which)."""
        return await self.send(calls.get_agent(agent_id, wait_frt_ms))

    async def delete_agent(self, agent_id: str) -> DeleteResult:
        """Forget the agent (404 if unknown)."""
        return await self.send(calls.delete_agent(agent_id))

    # ------------------------------------------------------------------ checks
    async def collision_check(
        self,
        agent_id: str,
        trajectory: Any = None,
        *,
        trajectories: Any = None,
        mode: Mode = "tube",
        collision_radius: float | None = None,
        deadline_ms: float | None = None,
        footprint: Any = None,
        include_clearance: bool = False,
    ) -> CollisionCheck:
        """Does the robot ``trajectory`` enter the agent's unsafe set C = K ⊕ R_col?

        Args:
            trajectory: ``(N, 3)`` rows ``(t, x, y)`` (t on the observations' clock), ``(N, 4)``
                rows ``(t, x, y, heading)``, or points.
            trajectories: instead of ``trajectory``, a batch of candidate trajectories (an
                ``(M, N, 3 or 4)`` array or a list of trajectories), each answered on its own in
                the answer's ``trajectories``.
            mode: ``"tube"`` (every point against the whole horizon) or ``"time_indexed"``.
            collision_radius: R_col in metres; default the agent's.
            deadline_ms: the service answers within it, conservatively if need be.
            footprint: the ego's box ``(length, width[, rear_axle_to_center])`` or a mapping,
                checked along each point's heading instead of the point (headings required).
            include_clearance: with ``trajectories``, each one's clearance per point too.
        """
        return await self.send(
            calls.collision_check(
                agent_id,
                trajectory,
                trajectories=trajectories,
                options=calls.CheckOptions(
                    mode, collision_radius, deadline_ms, footprint, include_clearance
                ),
            )
        )

    async def collision_check_many(
        self,
        trajectory: Any = None,
        agent_ids: Iterable[str] | None = None,
        *,
        trajectories: Any = None,
        mode: Mode = "tube",
        collision_radius: float | None = None,
        deadline_ms: float | None = None,
        footprint: Any = None,
        include_clearance: bool = False,
    ) -> MultiCollisionCheck:
        """The same check (see :meth:`collision_check`) against several agents in one call;
        ``agent_ids=None`` checks all."""
        return await self.send(
            calls.collision_check_many(
                trajectory,
                agent_ids,
                trajectories=trajectories,
                options=calls.CheckOptions(
                    mode, collision_radius, deadline_ms, footprint, include_clearance
                ),
            )
        )

    # ------------------------------------------------------------------ sets
    async def contours(
        self,
        agent_id: str,
        *,
        slices: Iterable[float] = (),
        include: Iterable[str] = ("K", "C"),
        tube: bool = True,
        collision_radius: float | None = None,
    ) -> AgentContours:
        """GeoJSON contours of the agent's K and C: the whole-horizon tube and time slices.

        Args:
            slices: seconds after the last observation, each in ``[0, horizon]``.
            include: any of ``"K"`` (the FRT) and ``"C"`` (K inflated by R_col).
            tube: include the whole-horizon tube.
        """
        return await self.send(
            calls.contours(
                agent_id,
                slices=slices,
                include=include,
                tube=tube,
                collision_radius=collision_radius,
            )
        )

    async def constraints(
        self,
        agent_id: str,
        *,
        slices: Iterable[float],
        collision_radius: float | None = None,
        max_sides: int | None = None,
        max_pieces: int | None = None,
    ) -> AgentConstraints:
        """Per time, convex pieces ``{x : A x <= b}`` in the world frame whose union contains
        the agent's C = K ⊕ R_col at that time: constraints for a planner's MPC.

        Args:
            slices: seconds after the last observation, each in ``[0, horizon]``.
            collision_radius: R_col of C (default: the agent's).
            max_sides: sides of one piece at most (3 to 64; default 16).
            max_pieces: pieces of one time at most (1 to 16; default 4).
        """
        return await self.send(
            calls.constraints(
                agent_id,
                slices=slices,
                collision_radius=collision_radius,
                max_sides=max_sides,
                max_pieces=max_pieces,
            )
        )

    async def frt(
        self,
        state: Any,
        *,
        control_bounds: Any = None,
        prediction: Any = None,
        beta: float | None = None,
        gamma: float | None = None,
        bounds_fit: str | None = None,
        bounds_rule: str | None = None,
        rescue_onset: float | None = None,
        collision_radius: float | None = None,
        contours: dict[str, Any] | None = None,
        trajectory: Any = None,
        mode: Mode = "tube",
        deadline_ms: float | None = None,
        timestamp: float = 0.0,
    ) -> FRTResult:
        """The stateless FRT: give ``control_bounds`` (eight numbers or a mapping), or a
        ``prediction`` and ``beta``; get contours (``contours={"slices": [...], "include":
        [...], "tube": bool}``) and/or a check of ``trajectory``. No agent is kept."""
        return await self.send(
            calls.frt(
                state,
                control_bounds=control_bounds,
                prediction=prediction,
                beta=beta,
                gamma=gamma,
                bounds_fit=bounds_fit,
                bounds_rule=bounds_rule,
                rescue_onset=rescue_onset,
                collision_radius=collision_radius,
                contours=contours,
                trajectory=trajectory,
                mode=mode,
                deadline_ms=deadline_ms,
                timestamp=timestamp,
            )
        )
