"""Prometheus metrics of one app instance (its own registry, so tests can build many apps)."""

from __future__ import annotations

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, generate_latest
from prometheus_client.exposition import CONTENT_TYPE_LATEST

#: Request latencies are in the low milliseconds: buckets from 0.25 ms to 10 s.
LATENCY_BUCKETS = (
    0.00025, 0.0005, 0.001, 0.002, 0.003, 0.005, 0.0075, 0.01, 0.015, 0.02, 0.03, 0.05, 0.075,
    0.1, 0.2, 0.5, 1.0, 2.5, 10.0,
)  # fmt: skip


class Metrics:
    content_type = CONTENT_TYPE_LATEST

    def __init__(self) -> None:
        self.registry = CollectorRegistry()
        self._define_latencies(self.registry)
        self._define_sets(self.registry)
        self._define_demand(self.registry)
        self._define_answers(self.registry)
        self._define_audit(self.registry)
        self._define_maps(self.registry)

    def _define_latencies(self, r: CollectorRegistry) -> None:
        self.request_seconds = Histogram(
            "frt_http_request_duration_seconds",
            "HTTP request latency, by route template, method and status",
            ["route", "method", "status"],
            buckets=LATENCY_BUCKETS,
            registry=r,
        )
        self.ws_message_seconds = Histogram(
            "frt_ws_message_duration_seconds",
            "WebSocket message handling time, by operation and outcome",
            ["op", "ok"],
            buckets=LATENCY_BUCKETS,
            registry=r,
        )

    def _define_sets(self, r: CollectorRegistry) -> None:
        self.event_loop_tubes = Counter(
            "frt_event_loop_tubes",
            "Tubes of exact sets drawn on the server's event loop for time-indexed checks (the "
            "workers draw the ones an agent's checks ask for: service.runtime.tube_demand)",
            registry=r,
        )
        self.frt_compute_seconds = Histogram(
            "frt_compute_seconds",
            "Time to compute one FRT set (exact: background; conservative: fallback)",
            ["kind"],
            buckets=LATENCY_BUCKETS,
            registry=r,
        )
        self.exact_phase_seconds = Histogram(
            "frt_exact_phase_seconds",
            "Where an exact set's time goes besides its computation (frt_compute_seconds): "
            "queued (submitted until a worker takes it) and transfer (the task to the worker and "
            "the set back in its binary layout, while the worker's own timing is not running)",
            ["phase"],
            buckets=LATENCY_BUCKETS,
            registry=r,
        )
        self.frt_cache = Counter(
            "frt_cache_lookups",
            "Exact-FRT cache lookups: hit (ready), pending (being computed) or miss",
            ["result"],
            registry=r,
        )
        self.refinements = Counter(
            "frt_refinements",
            "Background refinements of exact sets (the notch cut), by outcome: landed (it replaced "
            "the agent's current set), stale (it replaced its set, but a later version had come: "
            "checks no longer ask for it), dropped (its version superseded or its agent forgotten "
            "before it ran), wasted (it ran, but its set had left the cache), failed (it "
            "raised) or skipped (a later stage not started: it would have landed after the "
            "agent's next version came); and by stage (1 for a set's first refinement, 2 for the "
            "next)",
            ["outcome", "stage"],
            registry=r,
        )
        self.exact_sets = Counter(
            "frt_exact_sets",
            "Exact sets computed, by origin: observed (a version this replica stored from an "
            "observation), read (a version read from the store that this replica did not store or "
            "no longer holds: another replica's, or one rebuilt after its replica died; with "
            "requests of one scene routed to one replica, a set computed twice across replicas "
            "is counted here) or stateless (POST /v1/frt)",
            ["origin"],
            registry=r,
        )
        self.frt_failures = Counter(
            "frt_exact_failures", "Exact-FRT computations that raised", registry=r
        )

    def _define_demand(self, r: CollectorRegistry) -> None:
        """What demand-driven exact sets do: which sets start first, and the answers' verdicts."""
        self.exact_ready_seconds = Histogram(
            "frt_exact_ready_seconds",
            "From an exact set's submission to its set ready (queued, transferred, computed), by "
            "its priority when a worker took it: met (a planner's trajectory met the agent's "
            "set), demanded (came near it) or background",
            ["priority"],
            buckets=LATENCY_BUCKETS,
            registry=r,
        )
        self.exact_set_starts = Counter(
            "frt_exact_set_starts",
            "Exact sets handed to a worker, by priority: demanded (a planner's recent check came "
            "near the agent's set: service.runtime.demand) or background",
            ["priority"],
            registry=r,
        )
        self.check_verdicts = Counter(
            "frt_check_verdicts",
            "Per-agent collision answers by verdict: exact (from the exact set), decision_exact "
            "(from a set containing it that the trajectory clears) or conservative",
            ["verdict"],
            registry=r,
        )
        self.collisions_witnessed = Counter(
            "frt_collisions_witnessed",
            "Conservative collision answers whose collision a position the human reaches "
            "witnesses (collision_witnessed: the exact set's verdict is a collision too)",
            registry=r,
        )

    def _define_answers(self, r: CollectorRegistry) -> None:
        self.collision_checks = Counter(
            "frt_collision_checks",
            "Per-agent collision answers, by the set they came from",
            ["source"],
            registry=r,
        )
        self.conservative_reasons = Counter(
            "frt_conservative_answers",
            "Per-agent collision answers from a set containing the exact one, by why: the exact "
            "set not ready in time (not_ready), no time left to measure it (no_time), or tubes of "
            "a time-indexed check not drawn in time (tubes)",
            ["reason"],
            registry=r,
        )
        self.deadline_misses = Counter(
            "frt_deadline_misses",
            "Collision checks answered after their deadline",
            registry=r,
        )

    def _define_audit(self, r: CollectorRegistry) -> None:
        self.audit_positions = Counter(
            "frt_audit_positions",
            "Coverage audit: observed positions scored against an earlier version of their agent's "
            "sets (one per version whose horizon covers the observation), by agent class and by "
            "the set scored: the exact set (ready, its tube drawn) or the conservative one",
            ["agent_class", "source"],
            registry=r,
        )
        self.audit_misses = Counter(
            "frt_audit_misses",
            "Coverage audit: audited positions outside K (at that time: the tube up to it), or "
            "outside C = K + R_col, by set, agent class and source (as frt_audit_positions)",
            ["set", "agent_class", "source"],
            registry=r,
        )
        self.audit_coverage = Gauge(
            "frt_audit_coverage",
            "Coverage audit: share of the last audit_window audited positions inside K, or C",
            ["set"],
            registry=r,
        )
        self.agents = Gauge("frt_agents", "Agents in the store", registry=r)
        self.model_ready = Gauge("frt_model_ready", "1 once the model is loaded", registry=r)

    def _define_maps(self, r: CollectorRegistry) -> None:
        self.road_cuts = Counter(
            "frt_road_cuts",
            "Answers for a state that named a map (docs/maps.md), by outcome: cut (the set cut by "
            "its map assumptions) or off_road (the stateless state keeps none: answered uncut)",
            ["outcome"],
            registry=r,
        )
        self.assumption_violations = Counter(
            "frt_assumption_violations",
            "States observed breaking a map assumption (drivable_area: off the drivable area "
            "grown by FRT_MAP_MARGIN_M), by assumption and agent class",
            ["assumption", "agent_class"],
            registry=r,
        )
        self.assumption_misses = Counter(
            "frt_assumption_misses",
            "Audited positions inside an earlier version's uncut K but off the region of a map "
            "assumption that version was cut by (so its cut set misses them), by assumption and "
            "agent class (docs/maps.md)",
            ["assumption", "agent_class"],
            registry=r,
        )

    def render(self) -> bytes:
        return generate_latest(self.registry)
