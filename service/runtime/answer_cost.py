"""What answering a collision check costs here, per unit of work, by the set it is answered from.

Once a check's sets are known, answering is CPU work on the event loop: per agent, a signed distance
to its exact tube or to its conservative boxes at each of the check's probes, for each member of a
multi-modal agent's union, and its share of building the response. The work is counted in units
(:func:`work_units`): an agent of one mode checked at 20 probes is one unit of measuring and one of
answering; 32 modes at 1 000 probes are 816 of measuring and 25.5 of answering, so that one
estimate serves checks of any size. Under load each takes several times its quiet cost, so the
deadline logic (``service.flows.checks``) plans with an estimate that is rarely exceeded rather
than the average: per kind, a moving average of the cost per unit plus ``SPREAD`` moving mean
absolute deviations of it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

#: Weight of the newest measurement in the moving averages.
WEIGHT = 0.2
#: Deviations above the average that the estimate allows for.
SPREAD = 4.0
#: Share of the event loop's time that measuring left-out exact answers may take.
REMEASURE_SHARE = 0.1
#: Probes of a check that one unit of work is (with :data:`FIXED_PROBES`: a 20-point check).
UNIT_PROBES = 20
#: An agent's work that does not grow with the probes, as probes: its share of a check's fixed
#: cost (looking up its set, its answer's fields).
FIXED_PROBES = 20


def work_units(probes: int, members: Any = 1) -> Any:
    """Units of work (see the module) of measuring an agent whose set is a union of ``members``
    at ``probes`` probes (an array of agents' members: theirs); with ``members`` 1, also those
    of answering it."""
    return members * (probes + FIXED_PROBES) / (UNIT_PROBES + FIXED_PROBES)


@dataclass
class CostEstimate:
    """Seconds per unit of one kind of work: moving average and mean absolute deviation."""

    mean_s: float = 0.0
    deviation_s: float = 0.0
    measured: bool = False

    def record(self, seconds: float, units: float) -> None:
        if units <= 0:
            return
        per_unit = seconds / units
        if not self.measured:
            self.mean_s, self.deviation_s, self.measured = per_unit, per_unit / 2.0, True
            return
        self.deviation_s += WEIGHT * (abs(per_unit - self.mean_s) - self.deviation_s)
        self.mean_s += WEIGHT * (per_unit - self.mean_s)

    def upper_s(self, units: float) -> float:
        """Seconds that ``units`` units rarely exceed (0 before any measurement)."""
        return (self.mean_s + SPREAD * self.deviation_s) * units


@dataclass
class AnswerCosts:
    """Answering cost per unit from exact sets, from conservative sets, and the share of the
    response every agent needs."""

    exact: CostEstimate = field(default_factory=CostEstimate)
    conservative: CostEstimate = field(default_factory=CostEstimate)
    response: CostEstimate = field(default_factory=CostEstimate)
    #: When (``time.perf_counter()``) an exact answer a check left out may next be measured
    #: after it (``service.flows.checks``): each such measurement holds the event loop as long as
    #: that answer would have, so they take at most :data:`REMEASURE_SHARE` of its time.
    remeasure_after: float = -math.inf

    def remeasured(self, started: float, ended: float) -> None:
        """Note a measurement of a left-out exact answer from ``started`` to ``ended``."""
        self.remeasure_after = ended + (ended - started) * (1.0 / REMEASURE_SHARE - 1.0)

    def upper_s(self, exact_units: float, conservative_units: float, answered: float) -> float:
        """Seconds to measure that many units against each kind of set and answer ``answered``
        units, rarely exceeded."""
        return (
            self.exact.upper_s(exact_units)
            + self.conservative.upper_s(conservative_units)
            + self.response.upper_s(answered)
        )

    def exact_agents_within(
        self, seconds: float, exact_units: Sequence[float], all_units: float, answered: float
    ) -> int:
        """How many of the agents with exact sets (their units ``exact_units``, in order) can
        be answered from them within ``seconds``, the first ones first, when the others (of
        ``all_units`` in all, ``answered`` units of answering) are answered conservatively. All
        of them where an exact answer costs no more than a conservative one: answering an agent
        conservatively then saves no time."""
        per_exact = self.exact.upper_s(1)
        per_conservative = self.conservative.upper_s(1)
        extra = per_exact - per_conservative
        if extra <= 0.0:
            return len(exact_units)
        left = seconds - all_units * per_conservative - self.response.upper_s(answered)
        kept, units = 0, 0.0
        for agent_units in exact_units:
            units += agent_units
            if units * extra > left:
                break
            kept += 1
        return kept
