"""Lanelet2 maps: an OSM XML file (Lanelet2's and Autoware's format) read into a ``RoadMap``.

The XML is read directly (``defusedxml``: DTDs, entities and external references are refused),
not through the ``lanelet2`` package; the rules of its loader and routing graph that the cuts
need are reproduced here:

* **points**: a node's ``local_x``/``local_y`` tags (metres, Autoware's maps) when the map's
  nodes carry them; else its ``lat``/``lon`` projected about an origin (the one given, or the
  map's first node) by the local equirectangular projection
  ``x = R·Δλ·cos φ₀``, ``y = R·Δφ`` (R = 6 378 137 m), whose scale error grows as
  ``tan φ₀ · Δφ`` (about 0.16 m per km north or south of the origin at 45°);
* **lanelets**: relations tagged ``type=lanelet`` with exactly one ``left`` and one ``right``
  way member (and an optional ``centerline``). Each bound is oriented as Lanelet2's
  ``geometry::align`` does it: the left bound is reversed unless the right bound's middle point
  lies to its right, the right bound unless the left bound's middle point lies to its left. The
  lanelet is driven from the first to the last point of its oriented bounds;
  ``one_way=no`` (for vehicles) makes it a lane each way (the reverse one's id ends in
  ``:reverse``);
* **types** (the Lanelet2 tagging spec's ``subtype``, ``road`` when absent; ``participant:*``
  tags override it): ``road``, ``highway`` → ``VEHICLE`` (the lanes ``reachable_lanes``
  follows), ``bus_lane`` → ``BUS``, ``bicycle_lane`` → ``BIKE``, ``walkway``,
  ``shared_walkway``, ``stairs`` → ``PEDESTRIAN``, ``crosswalk`` → a pedestrian crossing (its
  bounds the two edges), any other subtype upper-cased;
* **successors** (Lanelet2's ``geometry::follows``): b follows a when a's oriented bounds end at
  the nodes b's start at (left at left, right at right);
* **neighbours** (Lanelet2's ``leftOf``): b is a's left neighbour when a's left bound is b's
  right bound, the same way in the same orientation (lanes going the same way); a way shared
  in opposite orientations joins oncoming lanes, which are not neighbours. Lane changes are
  followed whatever the shared line's marking;
* **the drivable area** D: the union of the polygons of the lanelets that are not for
  pedestrians alone, and of the ``type=multipolygon`` areas whose subtype is one of
  ``DRIVABLE_AREA_SUBTYPES`` (outer ways joined into rings by their end nodes, inner rings cut
  out);
* **speed limits** (m/s, per lanelet, both ways of a two-way one; None where not given): the
  highest of the speed limits the lanelet references (its ``regulatory_element`` relation
  members tagged ``subtype=speed_limit``, Lanelet2's ``SpeedLimit``), each read as
  Lanelet2's ``TrafficSign::type`` reads it: its first ``refers`` sign way's ``subtype``, else its
  ``sign_type`` tag, else its ``speed_limit`` tag. Without one, the highest of the lanelet's
  ``speed_limit`` and ``speed_limit:vehicle*`` tags (Lanelet2's tag and its vehicle overrides;
  Autoware's maps carry the tag), unless ``speed_limit_mandatory=no`` (a recommendation: None).
  The highest, not Lanelet2's first, and ``ref_line``/``cancel_line`` are not read: a limit that
  holds on part of a lanelet may be the one that holds there. Values (:func:`speed_value`):
  a number of km/h (``50``), or a number and a unit, km/h, kmh, mph, m/s, mps (``50 km/h``,
  ``30 mph``, ``13.9 m/s``: Lanelet2's ``Attribute::asVelocity`` units, any case), or the German
  sign ``de274-<n>`` (n km/h); above 0 and at most 500 km/h. Anything else is refused naming the
  tag (``relation.7.tag.sign_type``), and so is a referenced element that is not in the file or a
  speed limit with no value.

Bounded like an archive's points: the bytes by the caller, XML elements by ``MAX_ELEMENTS``,
nodes and the node references of ways by ``max_points`` each, ways by ``MAX_WAYS``, relations by
``MAX_RELATIONS``, relation members by ``max_points``. Errors are ``MapFormatError`` naming the
element by a dotted path (``relation.1234.member.left: way 55 not found``).
"""

from __future__ import annotations

import io
import math
import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import shapely
from defusedxml import DefusedXmlException
from defusedxml.ElementTree import ParseError, iterparse
from shapely.geometry.base import BaseGeometry

from reach.road_map import COORDINATE_LIMIT, MAX_POINTS, Crossing, Lane, MapFormatError, RoadMap

#: XML elements one file may hold (tags, nds and members included).
MAX_ELEMENTS = 4_000_000
#: Ways and relations one file may hold.
MAX_WAYS = 500_000
MAX_RELATIONS = 200_000
#: The equatorial radius of the projection (metres).
EARTH_RADIUS_M = 6_378_137.0
#: Lane types of Lanelet2 subtypes; a subtype not listed is upper-cased.
SUBTYPE_LANE_TYPES = {
    "road": "VEHICLE",
    "highway": "VEHICLE",
    "bus_lane": "BUS",
    "bicycle_lane": "BIKE",
    "walkway": "PEDESTRIAN",
    "shared_walkway": "PEDESTRIAN",
    "stairs": "PEDESTRIAN",
}
#: Lanelets of these lane types are left out of the drivable area.
PEDESTRIAN_TYPES = ("PEDESTRIAN", "NONE")
#: Multipolygon areas of these subtypes are part of the drivable area.
DRIVABLE_AREA_SUBTYPES = ("road", "highway", "parking", "freespace", "bus_lane", "bicycle_lane")
#: The suffix of the reverse lane of a two-way lanelet.
REVERSE = ":reverse"
#: Speed units read, in m/s per unit (Lanelet2's ``Attribute::asVelocity`` units); a number
#: without a unit is km/h, as in Lanelet2 and Autoware.
SPEED_UNITS = {"km/h": 1.0 / 3.6, "kmh": 1.0 / 3.6, "mph": 0.44704, "m/s": 1.0, "mps": 1.0}
#: A speed limit is a positive number (a decimal point allowed), optionally followed by a unit.
SPEED_PATTERN = re.compile(r"([0-9]+(?:\.[0-9]*)?|\.[0-9]+)\s*([a-z/]*)")
#: The German speed-limit sign ``de274-<n>``: n km/h (as Lanelet2's German traffic rules read it).
SIGN_PATTERN = re.compile(r"de274-([0-9]+)")
#: Speed limits above this (m/s, 500 km/h) are refused.
MAX_SPEED_LIMIT = 500.0 / 3.6


@dataclass
class _Element:
    """One node, way or relation as read: attributes, tags, node refs or (type, ref, role)."""

    attrs: dict[str, str]
    tags: dict[str, str] = field(default_factory=dict)
    refs: list[int] = field(default_factory=list)
    members: list[tuple[str, int, str]] = field(default_factory=list)


@dataclass
class OsmFile:
    """The nodes, ways and relations of a file, by id, in document order."""

    nodes: dict[int, _Element] = field(default_factory=dict)
    ways: dict[int, _Element] = field(default_factory=dict)
    relations: dict[int, _Element] = field(default_factory=dict)


def _integer(text: str | None, field_name: str) -> int:
    try:
        return int(text)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise MapFormatError(field_name, f"must be an integer id, got {text!r}") from None


class _Reader:
    """Counts what is read against the caps and files each element by kind and id."""

    def __init__(self, max_points: int) -> None:
        self.osm = OsmFile()
        self.caps = {"node": max_points, "way": MAX_WAYS, "relation": MAX_RELATIONS,
                     "nd": max_points, "member": max_points, "element": MAX_ELEMENTS}  # fmt: skip
        self.counts = dict.fromkeys(self.caps, 0)

    def count(self, kind: str, field_name: str) -> None:
        self.counts[kind] += 1
        if self.counts[kind] > self.caps[kind]:
            raise MapFormatError(field_name, f"the map holds more than {self.caps[kind]} {kind}s")

    def element(self, elem: Any) -> None:
        kind = elem.tag
        index = len(getattr(self.osm, kind + "s"))
        self.count(kind, kind)
        key = _integer(elem.get("id"), f"{kind}#{index}.id")
        item = _Element(dict(elem.attrib))
        for child in elem:
            self._child(kind, key, item, child)
        table = getattr(self.osm, kind + "s")
        if key in table:
            raise MapFormatError(f"{kind}.{key}", "a second element with this id")
        table[key] = item

    def _child(self, kind: str, key: int, item: _Element, child: Any) -> None:
        where = f"{kind}.{key}"
        if child.tag == "tag":
            item.tags[str(child.get("k"))] = str(child.get("v"))
        elif child.tag == "nd" and kind == "way":
            self.count("nd", where)
            item.refs.append(_integer(child.get("ref"), f"{where}.nd.{len(item.refs)}"))
        elif child.tag == "member" and kind == "relation":
            self.count("member", where)
            ref = _integer(child.get("ref"), f"{where}.member.{len(item.members)}.ref")
            item.members.append((str(child.get("type")), ref, str(child.get("role", ""))))


def read_osm(raw: bytes, max_points: int = MAX_POINTS) -> OsmFile:
    """The nodes, ways and relations of OSM XML bytes (``body`` named when it is not XML, holds
    a DTD or an entity, or is not an ``osm`` document)."""
    reader = _Reader(max_points)
    depth = 0
    try:
        for event, elem in iterparse(io.BytesIO(raw), events=("start", "end"), forbid_dtd=True):
            if event == "start":
                reader.count("element", "body")
                if depth == 0 and elem.tag != "osm":
                    raise MapFormatError("body", f"not an OSM document (root <{elem.tag}>)")
                depth += 1
                continue
            depth -= 1
            if depth == 1 and elem.tag in ("node", "way", "relation"):
                reader.element(elem)
                elem.clear()
    except ParseError as exc:
        raise MapFormatError("body", f"not XML: {exc}") from None
    except DefusedXmlException as exc:
        raise MapFormatError("body", f"refused: {type(exc).__name__} ({exc})") from None
    return reader.osm


def _number(text: str | None, field_name: str, limit: float) -> float:
    try:
        value = float(text)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise MapFormatError(field_name, f"must be a number, got {text!r}") from None
    if not math.isfinite(value) or abs(value) > limit:
        raise MapFormatError(field_name, f"must be finite and within ±{limit:g}")
    return value


class _Points:
    """Node ids to map-frame points: ``local_x``/``local_y`` when the map's nodes carry them,
    else ``lat``/``lon`` projected about the origin."""

    def __init__(self, osm: OsmFile, origin: tuple[float, float] | None) -> None:
        self.nodes = osm.nodes
        self.local = any("local_x" in n.tags or "local_y" in n.tags for n in osm.nodes.values())
        self.origin = origin
        if not self.local and origin is None and osm.nodes:
            first, node = next(iter(osm.nodes.items()))
            self.origin = self._lat_lon(first, node)
        self._cache: dict[int, tuple[float, float]] = {}

    @staticmethod
    def _lat_lon(key: int, node: _Element) -> tuple[float, float]:
        lat = _number(node.attrs.get("lat"), f"node.{key}.lat", 90.0)
        lon = _number(node.attrs.get("lon"), f"node.{key}.lon", 180.0)
        return lat, lon

    def point(self, key: int, where: str) -> tuple[float, float]:
        found = self._cache.get(key)
        if found is not None:
            return found
        node = self.nodes.get(key)
        if node is None:
            raise MapFormatError(where, f"node {key} not found")
        if self.local:
            limit = COORDINATE_LIMIT
            xy = tuple(
                _number(node.tags.get(k), f"node.{key}.tag.{k}", limit)
                for k in ("local_x", "local_y")
            )
        else:
            lat, lon = self._lat_lon(key, node)
            lat0, lon0 = self.origin  # type: ignore[misc]
            x = EARTH_RADIUS_M * math.radians(lon - lon0) * math.cos(math.radians(lat0))
            xy = (x, EARTH_RADIUS_M * math.radians(lat - lat0))
        self._cache[key] = xy  # type: ignore[assignment]
        return xy  # type: ignore[return-value]

    def way(self, osm: OsmFile, way_id: int, where: str) -> tuple[list[int], np.ndarray]:
        """The way's node ids and points; ``where`` names the member referring to it."""
        way = osm.ways.get(way_id)
        if way is None:
            raise MapFormatError(where, f"way {way_id} not found")
        if len(way.refs) < 2:
            raise MapFormatError(f"way.{way_id}", f"needs at least 2 nodes, got {len(way.refs)}")
        xy = [self.point(ref, f"way.{way_id}.nd.{i}") for i, ref in enumerate(way.refs)]
        return list(way.refs), np.array(xy, dtype=float)


def _side(line: np.ndarray, point: np.ndarray) -> float:
    """Positive where ``point`` lies left of ``line`` (on its nearest segment), negative right."""
    a, d = line[:-1], np.diff(line, axis=0)
    length2 = np.maximum((d * d).sum(axis=1), 1e-18)
    t = np.clip(((point - a) * d).sum(axis=1) / length2, 0.0, 1.0)
    k = int(np.argmin(np.hypot(*(a + t[:, None] * d - point).T)))
    r = point - a[k]
    return float(d[k, 0] * r[1] - d[k, 1] * r[0])


def _middle(line: np.ndarray) -> np.ndarray:
    return line[len(line) // 2] if len(line) > 2 else (line[0] + line[-1]) / 2.0


@dataclass
class _Lanelet:
    """One directed lanelet: its bounds' node ids, points and (way, reversed) keys."""

    id: str
    lane_type: str
    tags: dict[str, str]
    left_ids: list[int]
    right_ids: list[int]
    left: np.ndarray
    right: np.ndarray
    left_key: tuple[int, bool]
    right_key: tuple[int, bool]
    centerline: np.ndarray | None
    speed_limit: float | None = None

    def reversed(self) -> _Lanelet:
        """The lanelet driven the other way: bounds swapped and reversed."""
        return _Lanelet(
            self.id + REVERSE, self.lane_type, self.tags, self.right_ids[::-1],
            self.left_ids[::-1], self.right[::-1], self.left[::-1],
            (self.right_key[0], not self.right_key[1]), (self.left_key[0], not self.left_key[1]),
            None if self.centerline is None else self.centerline[::-1], self.speed_limit,
        )  # fmt: skip


def lane_type(tags: dict[str, str]) -> str:
    """The lane type of a lanelet's tags (see the module)."""
    allowed = {k.removeprefix("participant:") for k, v in tags.items()
               if k.startswith("participant:") and v == "yes"}  # fmt: skip
    if any(k.startswith("participant:") for k in tags):
        if any(
            k == "vehicle" or (k.startswith("vehicle:") and k != "vehicle:bus") for k in allowed
        ):
            return "VEHICLE"
        for name, kind in (
            ("vehicle:bus", "BUS"),
            ("bicycle", "BIKE"),
            ("pedestrian", "PEDESTRIAN"),
        ):
            if name in allowed:
                return kind
        return "NONE"
    subtype = tags.get("subtype", "road")
    return SUBTYPE_LANE_TYPES.get(subtype, subtype.upper())


def _one_member(element: _Element, role: str, where: str) -> int:
    refs = [ref for kind, ref, r in element.members if r == role and kind == "way"]
    if len(refs) != 1:
        raise MapFormatError(f"{where}.member.{role}", f"needs exactly one way, got {len(refs)}")
    return refs[0]


def _lanelet(osm: OsmFile, points: _Points, key: int, element: _Element) -> _Lanelet:
    """A lanelet relation read, its bounds oriented as Lanelet2's ``align`` orients them."""
    where = f"relation.{key}"
    ways = {role: _one_member(element, role, where) for role in ("left", "right")}
    left_ids, left = points.way(osm, ways["left"], f"{where}.member.left")
    right_ids, right = points.way(osm, ways["right"], f"{where}.member.right")
    flip_left = _side(left, _middle(right)) >= 0.0
    flip_right = _side(right, _middle(left)) <= 0.0
    if flip_left:
        left_ids, left = left_ids[::-1], left[::-1]
    if flip_right:
        right_ids, right = right_ids[::-1], right[::-1]
    centerline = None
    if any(role == "centerline" for _, _, role in element.members):
        _, centerline = points.way(
            osm, _one_member(element, "centerline", where), f"{where}.member.centerline"
        )
        start = (left[0] + right[0]) / 2.0
        if np.hypot(*(centerline[-1] - start)) < np.hypot(*(centerline[0] - start)):
            centerline = centerline[::-1]
    return _Lanelet(str(key), lane_type(element.tags), element.tags, left_ids, right_ids, left,
                    right, (ways["left"], flip_left), (ways["right"], flip_right), centerline,
                    _speed_limit(osm, key, element))  # fmt: skip


def speed_value(text: str, field_name: str) -> float:
    """A speed limit's value in m/s (see the module): ``50`` (km/h), ``50 km/h``, ``30 mph``,
    ``13.9 m/s`` and the other units of ``SPEED_UNITS`` (any case, spaces before the unit
    allowed), or the sign ``de274-<n>``; anything else is refused naming ``field_name``."""
    value = text.strip().lower()
    sign = SIGN_PATTERN.fullmatch(value)
    found = SPEED_PATTERN.fullmatch(value)
    if sign is not None:
        speed = float(sign.group(1)) / 3.6
    elif found is not None and (found.group(2) or "km/h") in SPEED_UNITS:
        speed = float(found.group(1)) * SPEED_UNITS[found.group(2) or "km/h"]
    else:
        units = ", ".join(SPEED_UNITS)
        raise MapFormatError(
            field_name, f"must be a speed (a number of km/h, or with a unit: {units}), got {text!r}"
        )
    if not 0.0 < speed <= MAX_SPEED_LIMIT:
        raise MapFormatError(field_name, f"must be above 0 and at most 500 km/h, got {text!r}")
    return speed


def _sign_limit(osm: OsmFile, key: int, element: _Element) -> float:
    """The limit (m/s) of a ``speed_limit`` regulatory element: its first ``refers`` sign's
    ``subtype`` where it has one (as Lanelet2's ``TrafficSign::type``), else its ``sign_type``
    tag, else its ``speed_limit`` tag."""
    where = f"relation.{key}"
    signs = [ref for kind, ref, role in element.members if kind == "way" and role == "refers"]
    if signs:
        sign = osm.ways.get(signs[0])
        if sign is None:
            raise MapFormatError(f"{where}.member.refers", f"way {signs[0]} not found")
        if "subtype" in sign.tags:
            return speed_value(sign.tags["subtype"], f"way.{signs[0]}.tag.subtype")
    for name in ("sign_type", "speed_limit"):
        if name in element.tags:
            return speed_value(element.tags[name], f"{where}.tag.{name}")
    raise MapFormatError(
        where, "a speed limit needs a refers sign's subtype, sign_type or speed_limit"
    )


def _speed_limit(osm: OsmFile, key: int, element: _Element) -> float | None:
    """A lanelet's speed limit (m/s; see the module): the highest of the ``speed_limit``
    regulatory elements it references, else the highest of its ``speed_limit`` and
    ``speed_limit:vehicle*`` tags (none when ``speed_limit_mandatory=no``), else None."""
    where = f"relation.{key}"
    limits = []
    for kind, ref, role in element.members:
        if role != "regulatory_element" or kind != "relation":
            continue
        rule = osm.relations.get(ref)
        if rule is None:
            raise MapFormatError(f"{where}.member.regulatory_element", f"relation {ref} not found")
        if rule.tags.get("subtype") == "speed_limit":
            limits.append(_sign_limit(osm, ref, rule))
    if limits:
        return max(limits)
    if element.tags.get("speed_limit_mandatory") == "no":
        return None
    tags = [
        speed_value(v, f"{where}.tag.{k}")
        for k, v in element.tags.items()
        if k == "speed_limit" or k.startswith("speed_limit:vehicle")
    ]
    return max(tags) if tags else None


def _two_way(tags: dict[str, str]) -> bool:
    return tags.get("one_way:vehicle", tags.get("one_way", "yes")) == "no"


def _lanes(directed: list[_Lanelet]) -> list[Lane]:
    """Lanes with successors (shared end and start nodes) and same-direction neighbours (a
    shared bound way in the same orientation)."""
    starts: dict[tuple[int, int], list[str]] = {}
    by_right: dict[tuple[int, bool], list[_Lanelet]] = {}
    by_left: dict[tuple[int, bool], list[_Lanelet]] = {}
    for ll in directed:
        starts.setdefault((ll.left_ids[0], ll.right_ids[0]), []).append(ll.id)
        by_right.setdefault(ll.right_key, []).append(ll)
        by_left.setdefault(ll.left_key, []).append(ll)
    ends: dict[str, list[str]] = {}
    for ll in directed:
        for nxt in starts.get((ll.left_ids[-1], ll.right_ids[-1]), []):
            ends.setdefault(nxt, []).append(ll.id)

    def neighbour(ll: _Lanelet, found: list[_Lanelet]) -> str | None:
        others = sorted(
            (o for o in found if o.id != ll.id), key=lambda o: o.lane_type != ll.lane_type
        )
        return others[0].id if others else None

    return [
        Lane(
            id=ll.id,
            lane_type=ll.lane_type,
            is_intersection="turn_direction" in ll.tags,
            left=ll.left,
            right=ll.right,
            centerline=ll.centerline,
            successors=tuple(starts.get((ll.left_ids[-1], ll.right_ids[-1]), [])),
            predecessors=tuple(ends.get(ll.id, [])),
            left_neighbor=neighbour(ll, by_right.get(ll.left_key, [])),
            right_neighbor=neighbour(ll, by_left.get(ll.right_key, [])),
            speed_limit=ll.speed_limit,
        )
        for ll in directed
    ]


def _rings(osm: OsmFile, ways: list[int], where: str) -> list[list[int]]:
    """The node-id rings the ways make, joined at shared end nodes."""
    pending = []
    for way_id in ways:
        way = osm.ways.get(way_id)
        if way is None:
            raise MapFormatError(where, f"way {way_id} not found")
        if len(way.refs) < 2:
            raise MapFormatError(f"way.{way_id}", f"needs at least 2 nodes, got {len(way.refs)}")
        pending.append(list(way.refs))
    rings = []
    while pending:
        ring = pending.pop(0)
        while len(ring) < 2 or ring[0] != ring[-1]:
            nxt = next((w for w in pending if ring[-1] in (w[0], w[-1])), None)
            if nxt is None:
                raise MapFormatError(where, f"its ways do not close a ring at node {ring[-1]}")
            pending.remove(nxt)
            ring += (nxt if nxt[0] == ring[-1] else nxt[::-1])[1:]
        rings.append(ring)
    return rings


def _area(osm: OsmFile, points: _Points, key: int, element: _Element) -> BaseGeometry:
    """A multipolygon area: its outer rings less its inner ones."""
    where = f"relation.{key}"
    geometry: list[BaseGeometry] = []
    for role in ("outer", "inner"):
        ways = [ref for kind, ref, r in element.members if kind == "way" and r == role]
        if role == "outer" and not ways:
            raise MapFormatError(f"{where}.member.outer", "needs at least one way")
        polygons = []
        for ring in _rings(osm, ways, f"{where}.member.{role}"):
            xy = [points.point(n, f"{where}.member.{role}") for n in ring]
            if len(xy) < 4:
                raise MapFormatError(f"{where}.member.{role}", "a ring needs at least 3 nodes")
            polygons.append(shapely.make_valid(shapely.Polygon(xy)))
        geometry.append(shapely.union_all(polygons) if polygons else shapely.Polygon())
    area = geometry[0].difference(geometry[1])
    if area.area <= 0.0:
        raise MapFormatError(where, "encloses no area")
    return area


def _lanelet_polygon(ll: _Lanelet) -> BaseGeometry | None:
    ring = np.vstack([ll.left, ll.right[::-1]])
    parts = shapely.get_parts(shapely.make_valid(shapely.Polygon(ring)))
    polygons = [p for p in parts if isinstance(p, shapely.Polygon) and p.area > 0.0]
    return shapely.union_all(polygons) if polygons else None


def parse_osm(
    raw: bytes, max_points: int = MAX_POINTS, origin: tuple[float, float] | None = None
) -> tuple[list[BaseGeometry], list[Lane], list[Crossing]]:
    """The drivable polygons, lanes and crossings of a Lanelet2 OSM file (see the module)."""
    osm = read_osm(raw, max_points)
    points = _Points(osm, origin)
    directed: list[_Lanelet] = []
    crossings: list[Crossing] = []
    areas: list[BaseGeometry] = []
    for key, element in osm.relations.items():
        kind = element.tags.get("type")
        if kind == "lanelet":
            ll = _lanelet(osm, points, key, element)
            if element.tags.get("subtype") == "crosswalk":
                crossings.append(Crossing(ll.id, ll.left, ll.right))
                continue
            directed.append(ll)
            if ll.lane_type not in PEDESTRIAN_TYPES and (polygon := _lanelet_polygon(ll)):
                areas.append(polygon)
            if _two_way(element.tags):
                directed.append(ll.reversed())
        elif kind == "multipolygon" and element.tags.get("subtype") in DRIVABLE_AREA_SUBTYPES:
            areas.append(_area(osm, points, key, element))
    if not areas:
        raise MapFormatError("body", "no drivable lanelet or area (a Lanelet2 map of roads?)")
    return areas, _lanes(directed), crossings


def road_map_from_osm(
    raw: bytes, max_points: int = MAX_POINTS, origin: tuple[float, float] | None = None
) -> RoadMap:
    """The ``RoadMap`` of a Lanelet2 OSM file."""
    return RoadMap(*parse_osm(raw, max_points, origin), map_format="lanelet2")
