"""What answering a collision check costs here, per agent, by the set it is answered from.

Once a check's sets are known, answering is CPU work on the event loop: per agent, a signed distance
to its exact tube (GEOS) or to its conservative boxes (one numpy pass for every such agent), and
its share of building the response. Under load each takes several
times its quiet cost, so the deadline logic (``service.flows.checks``) plans with an estimate that is
rarely exceeded rather than the average: per kind, a moving average of the cost per agent plus
``SPREAD`` moving mean absolute deviations of it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

#: Weight of the newest measurement in the moving averages.
WEIGHT = 0.2
#: Deviations above the average that the estimate allows for.
SPREAD = 4.0


@dataclass
class CostEstimate:
    """Seconds per agent of one kind of work: moving average and mean absolute deviation."""

    mean_s: float = 0.0
    deviation_s: float = 0.0
    measured: bool = False

    def record(self, seconds: float, agents: int) -> None:
        if agents <= 0:
            return
        per_agent = seconds / agents
        if not self.measured:
            self.mean_s, self.deviation_s, self.measured = per_agent, per_agent / 2.0, True
            return
        self.deviation_s += WEIGHT * (abs(per_agent - self.mean_s) - self.deviation_s)
        self.mean_s += WEIGHT * (per_agent - self.mean_s)

    def upper_s(self, agents: int) -> float:
        """Seconds that ``agents`` agents rarely exceed (0 before any measurement)."""
        return (self.mean_s + SPREAD * self.deviation_s) * agents


@dataclass
class AnswerCosts:
    """Answering cost per agent from exact sets, from conservative sets, and the share of the
    response every agent needs."""

    exact: CostEstimate = field(default_factory=CostEstimate)
    conservative: CostEstimate = field(default_factory=CostEstimate)
    response: CostEstimate = field(default_factory=CostEstimate)

    def upper_s(self, exact_agents: int, conservative_agents: int) -> float:
        """Seconds to answer that many agents from each kind of set, rarely exceeded."""
        return (
            self.exact.upper_s(exact_agents)
            + self.conservative.upper_s(conservative_agents)
            + self.response.upper_s(exact_agents + conservative_agents)
        )

    def exact_agents_within(self, seconds: float, exact_agents: int, agents: int) -> int:
        """How many of ``exact_agents`` can be answered from their exact sets within ``seconds``
        when the other agents (of ``agents`` in all) are answered conservatively. All of them
        where an exact answer costs no more than a conservative one: answering an agent
        conservatively then saves no time."""
        per_exact = self.exact.upper_s(1)
        per_conservative = self.conservative.upper_s(1)
        extra = per_exact - per_conservative
        if extra <= 0.0:
            return exact_agents
        base = agents * (per_conservative + self.response.upper_s(1))
        if base >= seconds:
            return 0
        return min(exact_agents, math.floor((seconds - base) / extra))
