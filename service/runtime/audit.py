"""The coverage audit: was the human where the service said it could be?

When an observation of an agent arrives at time t, its position is scored against every earlier
version of the agent's sets whose horizon covers t (``t0 < t <= t0 + horizon``, ``t0`` the
version's observation time): inside K at that time, i.e. within the tube up to ``t - t0`` (the
query a time-indexed collision check makes, ``FRTSet.clearance``), and inside C = K ⊕ R_col
(distance to K at most the version's collision radius). Each (position, earlier version) pair is
one audited position. A version is scored against positions at least ``spacing_s`` apart
(``FRT_AUDIT_SPACING_S``): at 10 Hz a position 0.1 s after the last scored one says little the
last did not.

The set scored is the one the service would answer a check from at audit time: the version's exact
set if it is still cached (the two latest versions, ``VERSIONS_PER_AGENT``) and the position's tube
is drawn, else its conservative set, which contains it (a miss of the conservative set is a miss
of the exact one; a hit may not be). Which one is recorded (``source``). The conservative set of
every version is built by its observation anyway (``Services.conservative``); the ledger keeps a
reference to it (about 3.3 kB) for the agent's latest ``audit_max_versions`` versions whose
horizon has not ended, and forgets an agent not observed for the agent TTL.

When: after the observation's answer is sent (a frame's positions a few at a time per turn of
the event loop, ``service.flows.agents``), so the observation does not wait for it, unless the
agent has adaptive gamma (``coverage_target``), whose next bounds depend on it: then before its
new state is built. The ledger, and so each agent's counts, is the
process's own: with several replicas an observation is scored against the versions its replica
served, and ``GET /v1/agents/{id}`` reports the counts of the replica that answers it.
"""

from __future__ import annotations

import math
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from reach.batch import tube_clearances
from reach.distances import box_union_distances_until
from reach.frames import paired_human_frames
from reach.sets import BoxTubeSet, FRTSet
from reach.union import box_members
from service.runtime.maps import RoadProbe, VersionRoad
from service.runtime.metrics import Metrics
from service.runtime.scheduler import VERSIONS_PER_AGENT, FRTKey

#: Slack on "the horizon covers t" (float round-off of timestamps on a 0.1 s grid).
HORIZON_SLACK_S = 1e-9


@dataclass(frozen=True, slots=True)
class ServedVersion:
    """One version of an agent's sets, as the audit needs it."""

    version: int
    key: FRTKey
    #: The observation time of the version and the end of its horizon.
    t0: float
    horizon_end: float
    collision_radius: float
    agent_class: str
    #: The version's conservative set (contains its exact set).
    conservative: FRTSet
    #: The map and the assumptions the version was answered under (None: no map, or none).
    road: VersionRoad | None = None


class _AgentAudit:
    """One agent's recent versions, when each was last scored, its counts (``fold``) and when it
    was last recorded."""

    __slots__ = ("counts", "last_scored", "mapped", "recorded_at", "versions")

    def __init__(self, max_versions: int) -> None:
        self.versions: deque[ServedVersion] = deque(maxlen=max_versions)
        self.last_scored: dict[int, float] = {}  # version -> time of its last scored position
        self.counts: dict[str, Any] | None = None
        self.recorded_at = 0.0
        #: Whether a version recorded for the agent was cut by map assumptions.
        self.mapped = False


class AuditLedger:
    """Per agent, its latest ``max_versions`` served versions whose horizon has not ended before
    the latest (oldest first) and its audit counts, for at most ``max_agents`` agents recorded
    within ``ttl_s`` (the least recently recorded go first). A version is scored against
    positions at least ``spacing_s`` apart (0: every position). Thread-safe."""

    def __init__(
        self,
        max_versions: int,
        max_agents: int,
        ttl_s: float = math.inf,
        clock: Callable[[], float] = time.monotonic,
        spacing_s: float = 0.0,
    ) -> None:
        self._max_versions = max_versions
        self._spacing_s = spacing_s
        self._max_agents = max_agents
        self._ttl_s = ttl_s
        self._clock = clock
        self._agents: OrderedDict[str, _AgentAudit] = OrderedDict()
        self._lock = threading.Lock()

    def due(self, agent_id: str, t: float) -> list[ServedVersion]:
        """The agent's versions to score a position observed at ``t`` against, oldest first: those
        whose horizon covers ``t`` and that were last scored at least ``spacing_s`` before ``t``
        (or never), each then marked scored at ``t``."""
        with self._lock:
            entry = self._agents.get(agent_id)
            if entry is None:
                return []
            last, earliest = entry.last_scored, t - self._spacing_s + HORIZON_SLACK_S
            due = [  # those whose horizon covers t, t0 < t <= horizon_end
                v
                for v in entry.versions
                if v.t0 < t <= v.horizon_end + HORIZON_SLACK_S
                and last.get(v.version, -math.inf) <= earliest
            ]
            for v in due:
                last[v.version] = t
            return due

    def record(self, agent_id: str, served: ServedVersion) -> None:
        """Add the agent's new version (starting afresh if it is not above the last recorded: the
        agent was created again)."""
        now = self._clock()
        with self._lock:
            entry = self._agents.pop(agent_id, None)
            if entry is None or (entry.versions and entry.versions[-1].version >= served.version):
                entry = _AgentAudit(self._max_versions)
            versions = entry.versions
            # Timestamps increase per agent: a horizon ended before this version covers nothing.
            while versions and versions[0].horizon_end + HORIZON_SLACK_S < served.t0:
                versions.popleft()
            versions.append(served)
            if served.road is not None:
                entry.mapped = True
            if len(entry.last_scored) > len(versions):
                oldest = versions[0].version
                entry.last_scored = {v: t for v, t in entry.last_scored.items() if v >= oldest}
            entry.recorded_at = now
            self._agents[agent_id] = entry
            agents = self._agents
            while len(agents) > self._max_agents or (
                agents and next(iter(agents.values())).recorded_at < now - self._ttl_s
            ):
                agents.popitem(last=False)  # the least recently recorded: expired, or over the cap

    def add(self, agent_id: str, scored: Sequence[Scored], t: float) -> bool:
        """Count the positions ``scored`` at ``t`` into the agent's counts (``fold``); whether
        the agent has versions cut by map assumptions (then they count ``Scored.off`` too)."""
        with self._lock:
            entry = self._agents.get(agent_id)
            if entry is None:
                return False
            entry.counts = fold(entry.counts, scored, t, entry.mapped)
            return entry.mapped

    def counts(self, agent_id: str) -> dict[str, Any] | None:
        """The agent's counts (``fold``), None if nothing was audited."""
        with self._lock:
            entry = self._agents.get(agent_id)
            return None if entry is None or entry.counts is None else dict(entry.counts)

    def forget(self, agent_id: str) -> None:
        with self._lock:
            self._agents.pop(agent_id, None)

    def __len__(self) -> int:
        with self._lock:
            return len(self._agents)


class Scored(NamedTuple):
    """One audited position: the distance from the observed position to K of ``version`` at the
    observation's time (negative inside), and the version's collision radius. (A named tuple:
    a frame's audit makes thousands.)"""

    version: int
    t_rel: float
    distance_to_k: float
    collision_radius: float
    exact: bool
    agent_class: str
    #: The map assumptions that cut the version's set whose region the position is off, where
    #: the uncut K holds it: the cut set misses it for them (``VersionRoad.off``).
    off: tuple[str, ...] = ()

    @property
    def in_k(self) -> bool:
        return self.distance_to_k <= 0.0

    @property
    def in_c(self) -> bool:
        return self.distance_to_k <= self.collision_radius

    @property
    def source(self) -> str:
        return "exact" if self.exact else "conservative"


#: One observed position to score: (x, y, t, the agent's versions whose horizon covers t).
Position = tuple[float, float, float, Sequence[ServedVersion]]


def score(
    x: float,
    y: float,
    t: float,
    versions: Sequence[ServedVersion],
    exact_of: Callable[[FRTKey], FRTSet | None],
) -> list[Scored]:
    """The position (x, y) observed at ``t`` against each of ``versions`` (which cover ``t``),
    each from its exact set if ``exact_of`` has it with the tube drawn, else its conservative set
    (:func:`score_many` of one position)."""
    return score_many([(x, y, t, versions)], exact_of)[0]


def score_many(
    positions: Sequence[Position], exact_of: Callable[[FRTKey], FRTSet | None]
) -> list[list[Scored]]:
    """:func:`score` of each position (a frame's agents): the box sets of every position (each
    member of a multi-modal agent's union of them, its distance the least of its members') in
    one vectorised call, the exact sets position by position, in one call each."""
    pairs: list[tuple[int, ServedVersion, float, FRTSet, bool]] = []
    mapped: list[int] = []  # the pairs of versions cut by map assumptions
    for p, (_, _, t, versions) in enumerate(positions):
        # Only an agent's latest versions' exact sets are cached: the older are not looked up.
        cached_from = max((v.version for v in versions), default=0) - VERSIONS_PER_AGENT + 1
        for v in versions:
            frt = exact_of(v.key) if v.version >= cached_from else None
            usable = (
                frt is not None
                and frt.clearance_from_tubes
                and not frt.missing_tubes([frt.tube_index(t - v.t0)])
            )
            if v.road is not None:
                mapped.append(len(pairs))
            pairs.append((p, v, t - v.t0, frt if usable else v.conservative, usable))  # type: ignore[arg-type]
    xy = np.array([[x, y] for x, y, _, _ in positions], dtype=np.float64).reshape(-1, 2)
    distance = np.empty(len(pairs))
    members = [(i, m) for i, pair in enumerate(pairs) for m in _boxes_of(pair[3], pair[4])]
    if members:
        found = _box_distances(
            [m for _, m in members],
            xy[[pairs[i][0] for i, _ in members]],
            np.array([pairs[i][2] for i, _ in members]),
        )
        distance[:] = np.inf
        np.minimum.at(distance, [i for i, _ in members], found)
    boxed = {i for i, _ in members}
    exact: dict[int, list[int]] = {}  # per position, its pairs from exact sets
    for i, (p, _, t_rel, frt, usable) in enumerate(pairs):
        if usable:
            exact.setdefault(p, []).append(i)
        elif i not in boxed:  # a set of another kind
            distance[i] = float(frt.clearance(xy[p : p + 1], np.array([t_rel]))[0])
    for p, rows in exact.items():
        t_rel = [np.array([pairs[i][2]]) for i in rows]
        found_exact = tube_clearances([pairs[i][3] for i in rows], xy[p : p + 1], t_rel)
        distance[rows] = [float(d[0]) for d in found_exact]
    out: list[list[Scored]] = [[] for _ in positions]
    for (p, v, t_rel, _, usable), d in zip(pairs, distance.tolist(), strict=True):
        out[p].append(Scored(v.version, float(t_rel), d, v.collision_radius, usable, v.agent_class))
    if mapped:
        _mark_off(out, pairs, mapped, distance, xy)
    return out


def _mark_off(
    out: list[list[Scored]],
    pairs: Sequence[tuple[int, ServedVersion, float, FRTSet, bool]],
    mapped: Sequence[int],
    distance: np.ndarray,
    xy: np.ndarray,
) -> None:
    """Mark in ``out`` each ``mapped`` pair inside its set's uncut K with the assumptions whose
    region its position is off (``Scored.off``): each position read on its map once
    (``VersionRoad.probe``), then set operations per pair."""
    probes: dict[tuple[int, int], RoadProbe] = {}  # per position and map registration
    for i in mapped:
        p, v, _, frt, _ = pairs[i]
        if distance[i] > 0.0:  # outside the uncut set already: a miss of K, not the map's
            continue
        road: VersionRoad = v.road  # type: ignore[assignment]
        at = (p, road.entry.generation)
        probe = probes.get(at)
        if probe is None:
            probe = probes[at] = road.probe(float(xy[p, 0]), float(xy[p, 1]))
        off = road.off(frt, probe)
        if off:
            first = i  # the position's first pair: pairs run position by position
            while first and pairs[first - 1][0] == p:
                first -= 1
            out[p][i - first] = out[p][i - first]._replace(off=off)


def _boxes_of(frt: FRTSet, exact: bool) -> list[BoxTubeSet]:
    """The box sets whose least distance is ``frt``'s (``reach.union.box_members``), unless
    it is measured as an exact set."""
    return [] if exact else box_members(frt)


def _box_distances(sets: list[BoxTubeSet], xy: np.ndarray, t_rel: np.ndarray) -> np.ndarray:
    """``sets[i].clearance(xy[i], t_rel[i])`` of each i (``BoxTubeSet.clearance``'s arithmetic,
    ``reach.distances.box_union_distances_until``), together for the sets with as many boxes."""
    out = np.empty(len(sets))
    groups: dict[int, list[int]] = {}
    for i, frt in enumerate(sets):
        groups.setdefault(len(frt.boxes), []).append(i)
    for members in groups.values():
        group = [sets[i] for i in members]
        x, y = paired_human_frames(xy[members], [s.pose for s in group])
        limit = _boxes_until(group, t_rel[members])
        # [P, M, 4], as np.stack makes it, at less cost for a few hundred small arrays
        boxes = np.concatenate([s.boxes for s in group]).reshape(len(group), -1, 4)
        found = box_union_distances_until(x[:, None], y[:, None], boxes, limit[:, None])
        out[members] = found[:, 0]
    return out


def _boxes_until(sets: list[BoxTubeSet], t_rel: np.ndarray) -> np.ndarray:
    """How many boxes of each set its tube up to its time holds (``BoxTubeSet.clearance``'s),
    in one call where the sets share their slices and layout (one engine's do)."""
    first = sets[0]
    until, grid = first.boxes_until, (first.slice_dt, first.horizon_s, first.n_slices)
    shared = all(
        s.boxes_until is until and (s.slice_dt, s.horizon_s, s.n_slices) == grid for s in sets
    )
    if shared:
        return first.boxes_until[first.tube_indices(t_rel)]  # type: ignore[no-any-return]
    return np.array(
        [s.boxes_until[s.tube_indices(t_rel[i : i + 1])[0]] for i, s in enumerate(sets)]
    )


def fold(
    counts: dict[str, Any] | None, scored: Sequence[Scored], t: float, mapped: bool = False
) -> dict[str, Any]:
    """An agent's audit counts after the positions ``scored`` at ``t``:
    audited, missed in K and in C, how many came from exact sets, the last miss (the worst of
    the latest observation with one) and, for an agent with versions cut by map assumptions
    (``mapped``), the positions each assumption's cut missed (``assumption_misses``: by name,
    present once one has)."""
    out = dict(counts) if counts else {"audited": 0, "missed_k": 0, "missed_c": 0, "exact": 0}
    out.setdefault("last_miss", None)
    missed_k = missed_c = exact = 0
    worst: Scored | None = None  # the first of the misses of K farthest outside it
    for s in scored:  # one pass: a frame folds some 800 positions
        if not s.in_k:
            missed_k += 1
            if worst is None or s.distance_to_k > worst.distance_to_k:
                worst = s
        missed_c += not s.in_c
        exact += s.exact
    out["audited"] += len(scored)
    out["missed_k"] += missed_k
    out["missed_c"] += missed_c
    out["exact"] += exact
    off = [name for s in scored for name in s.off] if mapped else []
    if off:
        by_name = dict(out.get("assumption_misses") or {})
        for name in off:
            by_name[name] = by_name.get(name, 0) + 1
        out["assumption_misses"] = by_name
    if worst is not None:
        out["last_miss"] = {
            "timestamp": t,
            "frt_version": worst.version,
            "t_rel_s": worst.t_rel,
            "distance_outside_k_m": worst.distance_to_k,
            "distance_outside_c_m": (
                None if worst.in_c else worst.distance_to_k - worst.collision_radius
            ),
            "source": worst.source,
        }
    return out


class RollingCoverage:
    """Share of the last ``window`` audited positions inside K and inside C (fleet-wide)."""

    def __init__(self, window: int) -> None:
        self._k: deque[bool] = deque(maxlen=window)
        self._c: deque[bool] = deque(maxlen=window)
        self._lock = threading.Lock()

    def add(self, scored: Sequence[Scored]) -> tuple[float, float]:
        """Add positions; the coverage of K and of C over the window after them."""
        in_k = [s.in_k for s in scored]
        in_c = [s.in_c for s in scored]
        with self._lock:
            self._k.extend(in_k)  # the oldest leave as these come
            self._c.extend(in_c)
            n = len(self._k)
            return (sum(self._k) / n, sum(self._c) / n) if n else (1.0, 1.0)


def count_audited(
    metrics: Metrics,
    ledger: AuditLedger,
    coverage: RollingCoverage,
    agent_id: str,
    scored: Sequence[Scored],
    t: float,
) -> None:
    """Count audited positions into the agent's counts, the fleet's rolling coverage and the
    ``frt_audit_*`` metrics (:func:`count_audited_many` of one agent)."""
    count_audited_many(metrics, ledger, coverage, [(agent_id, scored, t)])


def count_audited_many(
    metrics: Metrics,
    ledger: AuditLedger,
    coverage: RollingCoverage,
    audited: Sequence[tuple[str, Sequence[Scored], float]],
) -> None:
    """Count each agent's audited positions (agent, positions, time) into its counts, then all
    of them into the fleet's rolling coverage and the ``frt_audit_*`` metrics (one counter
    update per label set)."""
    every: list[Scored] = []
    mapped: list[Scored] = []
    for agent_id, scored, t in audited:
        if scored:
            if ledger.add(agent_id, scored, t):
                mapped += scored
            every += scored
    if not every:
        return
    if mapped:
        count_assumption_misses(metrics, mapped)
    groups: dict[tuple[str, str], list[Scored]] = {}
    for s in every:
        groups.setdefault((s.agent_class, s.source), []).append(s)
    for (klass, source), members in groups.items():
        metrics.audit_positions.labels(klass, source).inc(len(members))
        for part, missed in (
            ("K", sum(not s.in_k for s in members)),
            ("C", sum(not s.in_c for s in members)),
        ):
            if missed:
                metrics.audit_misses.labels(part, klass, source).inc(missed)
    in_k, in_c = coverage.add(every)
    metrics.audit_coverage.labels("K").set(in_k)
    metrics.audit_coverage.labels("C").set(in_c)


def count_assumption_misses(metrics: Metrics, scored: Sequence[Scored]) -> None:
    """Count the positions whose versions' cut sets missed them, per assumption and agent class
    (``frt_assumption_misses_total``; ``Scored.off``)."""
    off: dict[tuple[str, str], int] = {}
    for s in scored:
        for name in s.off:
            off[name, s.agent_class] = off.get((name, s.agent_class), 0) + 1
    for (name, klass), n in off.items():
        metrics.assumption_misses.labels(name, klass).inc(n)
