"""The road assumption of a state that names a map (docs/maps.md): its set cut to the drivable
area while the state is on it.

A state off R = D ⊕ ``FRT_MAP_MARGIN_M`` (within the map's extent) breaks the assumption already:
its set is served uncut, with no assumption listed, and the breach is counted
(``frt_assumption_violations_total{assumption="drivable_area"}``).
"""

from __future__ import annotations

from collections.abc import Hashable

from reach.road_cut import DRIVABLE_AREA
from reach.sets import FRTSet
from service.runtime.maps import MapEntry
from service.runtime.services import Services


def map_entry(services: Services, map_id: str | None, field: str = "map_id") -> MapEntry | None:
    """The registered map a request names (422 naming ``field`` if unknown), None if it names
    none."""
    return None if map_id is None else services.maps.require(map_id, field)


def on_the_road(
    services: Services,
    entry: MapEntry | None,
    key: Hashable,
    frt: FRTSet,
    xy: tuple[float, float],
    agent_class: str,
) -> tuple[FRTSet, list[str]]:
    """``frt`` cut by the map's drivable area and the assumptions it was cut by, for a state at
    world position ``xy``: ``frt`` itself and none without a map or off the road. The cut is
    kept per (``key``, whether ``frt`` is conservative) while ``frt`` is the set answered from."""
    if entry is None:
        return frt, []
    if not entry.road.on_road(xy[0], xy[1], services.maps.margin):
        services.metrics.road_cuts.labels("off_road").inc()
        services.metrics.assumption_violations.labels(DRIVABLE_AREA, agent_class).inc()
        return frt, []
    services.metrics.road_cuts.labels("cut").inc()
    return services.maps.cut(entry, (key, frt.conservative), frt), [DRIVABLE_AREA]
