"""Lanelet2 OSM maps (``reach.lanelet2_map``) against the Argoverse 2 archive they are built from.

The shipped archive (data/av2/, © Argo AI, LLC, CC BY-NC-SA 4.0,
https://creativecommons.org/licenses/by-nc-sa/4.0/) is written here as a Lanelet2 OSM file by its
geometry alone: each lane segment a ``lanelet`` whose left and right ways are its boundaries, a
node per distinct point (so lanes that meet share nodes, and boundaries drawn alike share ways,
either way round), each drivable area a ``multipolygon`` of subtype ``road``, each crossing a
``crosswalk`` lanelet; nodes carry ``local_x``/``local_y``. The archive's own links (successors,
neighbours) are not written: the OSM reader finds them from the shared nodes and ways, and they
are checked against the archive's. The two maps are registered over the API and cut alike.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np
import pytest
import shapely
from fastapi.testclient import TestClient
from shapely.geometry import shape

from reach.lanelet2_map import EARTH_RADIUS_M, REVERSE, road_map_from_osm
from reach.lanes import lane_area
from reach.road_map import MapFormatError, RoadMap
from service.api.app import create_app
from tests.test_maps_api import ARCHIVE, ON_ROAD, RAW, frt, settings_for, wait_ready

LANE_SUBTYPES = {"VEHICLE": "road", "BUS": "bus_lane", "BIKE": "bicycle_lane"}
XML = {"content-type": "application/osm+xml"}


class OsmWriter:
    """OSM XML of points, ways and relations; a node per distinct point (to the centimetre), a
    way per distinct node sequence (its reverse reusing it)."""

    def __init__(self, lat_lon_origin: tuple[float, float] | None = None) -> None:
        self.nodes: dict[tuple[float, float], int] = {}
        self.ways: dict[tuple[int, ...], int] = {}
        self.relations: list[str] = []
        self.origin = lat_lon_origin

    def node(self, point: dict) -> int:
        key = (round(point["x"], 2), round(point["y"], 2))
        return self.nodes.setdefault(key, len(self.nodes) + 1)

    def way(self, points: list[dict], closed: bool = False) -> int:
        ids = [self.node(p) for p in points]
        ids = [n for i, n in enumerate(ids) if i == 0 or n != ids[i - 1]]
        key = (*ids, ids[0]) if closed else tuple(ids)
        found = self.ways.get(key) or self.ways.get(key[::-1])
        return found if found is not None else self.ways.setdefault(key, len(self.ways) + 1)

    def relation(self, key: int, members: list[tuple[int, str]], tags: dict[str, str]) -> None:
        lines = [f'  <relation id="{key}">']
        lines += [f'    <member type="way" ref="{ref}" role="{role}"/>' for ref, role in members]
        lines += [f"    <tag k={quoteattr(k)} v={quoteattr(v)}/>" for k, v in tags.items()]
        self.relations.append("\n".join([*lines, "  </relation>"]))

    def _node_xml(self, xy: tuple[float, float], key: int) -> str:
        if self.origin is None:
            return (f'  <node id="{key}" lat="0" lon="0"><tag k="local_x" v="{xy[0]}"/>'
                    f'<tag k="local_y" v="{xy[1]}"/></node>')  # fmt: skip
        lat0, lon0 = self.origin
        lat = lat0 + math.degrees(xy[1] / EARTH_RADIUS_M)
        lon = lon0 + math.degrees(xy[0] / (EARTH_RADIUS_M * math.cos(math.radians(lat0))))
        return f'  <node id="{key}" lat="{lat!r}" lon="{lon!r}"/>'

    def xml(self) -> bytes:
        out = ['<?xml version="1.0" encoding="UTF-8"?>', '<osm version="0.6">']
        out += [self._node_xml(xy, key) for xy, key in self.nodes.items()]
        for refs, key in self.ways.items():
            out.append(f'  <way id="{key}">' + "".join(f'<nd ref="{n}"/>' for n in refs) + "</way>")
        return "\n".join([*out, *self.relations, "</osm>"]).encode()


def osm_of(archive: dict, origin: tuple[float, float] | None = None) -> bytes:
    """The archive as a Lanelet2 OSM file (see the module), lat/lon about ``origin`` if given."""
    writer = OsmWriter(origin)
    for key, lane in archive["lane_segments"].items():
        left, right = (
            writer.way(lane["left_lane_boundary"]),
            writer.way(lane["right_lane_boundary"]),
        )
        tags = {"type": "lanelet", "subtype": LANE_SUBTYPES[lane["lane_type"]]}
        writer.relation(int(key), [(left, "left"), (right, "right")], tags)
    for i, area in enumerate(archive["drivable_areas"].values()):
        ring = writer.way(area["area_boundary"], closed=True)
        writer.relation(i + 1, [(ring, "outer")], {"type": "multipolygon", "subtype": "road"})
    for i, crossing in enumerate(archive["pedestrian_crossings"].values()):
        edges = [(writer.way(crossing["edge1"]), "left"), (writer.way(crossing["edge2"]), "right")]
        writer.relation(100 + i, edges, {"type": "lanelet", "subtype": "crosswalk"})
    return writer.xml()


@pytest.fixture(scope="module")
def archive() -> dict:
    return json.loads(RAW)


@pytest.fixture(scope="module")
def osm(archive: dict) -> bytes:
    return osm_of(archive)


@pytest.fixture(scope="module")
def client(analytic_model_path: Path, osm: bytes) -> Iterator[TestClient]:
    app = create_app(settings_for(analytic_model_path, max_maps=4))
    with TestClient(app, raise_server_exceptions=False) as test_client:
        wait_ready(test_client)
        assert test_client.put("/v1/maps/av2", content=RAW).status_code == 200
        r = test_client.put("/v1/maps/osm", content=osm, headers=XML)
        assert r.status_code == 200, r.text
        yield test_client


def test_the_osm_map_registers_with_the_archive_counts(client: TestClient, osm: bytes) -> None:
    body = client.get("/v1/maps/osm").json()
    assert body["format"] == "lanelet2" and client.get("/v1/maps/av2").json()["format"] == (
        "argoverse2"
    )
    assert (body["lane_segments"], body["pedestrian_crossings"]) == (71, 6)
    assert body["size_bytes"] == len(osm)
    # No content type: told by the first non-blank byte (here without the XML declaration).
    r = client.put("/v1/maps/sniffed", content=b"\n  " + osm.split(b"\n", 1)[1])
    assert r.status_code == 200 and r.json()["format"] == "lanelet2", r.text
    assert client.delete("/v1/maps/sniffed").status_code == 200


def test_the_drivable_area_covers_the_archive_lanes_and_areas(archive: dict, osm: bytes) -> None:
    road_osm, road_av2 = road_map_from_osm(osm), RoadMap.from_archive(archive)
    lanes = shapely.union_all([lane_area(lane) for lane in road_av2.lanes])
    assert lanes.difference(road_osm.drivable).area < 1e-6 * lanes.area
    assert road_av2.drivable.difference(road_osm.drivable).area < 1e-6 * road_av2.drivable.area
    # D of the OSM map is the archive's drivable areas and lanes, nothing else.
    expected = shapely.union(road_av2.drivable, lanes)
    assert shapely.symmetric_difference(expected, road_osm.drivable).area < 1e-6 * expected.area
    assert road_osm.extent == pytest.approx(road_av2.extent, abs=0.01)


def test_successors_and_neighbours_are_the_archive_links(archive: dict, osm: bytes) -> None:
    road_osm, road_av2 = road_map_from_osm(osm), RoadMap.from_archive(archive)
    held = set(archive["lane_segments"])
    osm_lanes = {lane.id: lane for lane in road_osm.lanes}
    assert set(osm_lanes) == held
    for key, lane in archive["lane_segments"].items():
        expected = {str(s) for s in lane["successors"]} & held
        assert set(osm_lanes[key].successors) == expected, key
        assert set(osm_lanes[key].predecessors) == {str(s) for s in lane["predecessors"]} & held
    # The lanes each one leads to (successors and same-direction neighbours) are the archive's.
    assert follows(road_osm) == follows(road_av2)
    changes = sum(len(f) for f in follows(road_av2).values()) - sum(
        len(set(map(str, lane["successors"])) & held) for lane in archive["lane_segments"].values()
    )
    assert changes > 10  # same-direction lane changes are among them


def follows(road: RoadMap) -> dict[str, set[str]]:
    graph = road.lane_graph
    return {graph.ids[i]: {graph.ids[j] for j in nexts} for i, nexts in enumerate(graph.follow)}


def test_a_car_is_cut_alike_on_both_maps(client: TestClient) -> None:
    cuts = {}
    for map_id in ("av2", "osm"):
        answer = frt(client, ON_ROAD, map_id=map_id)
        assert answer["assumptions"] == ["drivable_area", "reachable_lanes"], map_id
        cuts[map_id] = {part: shape(answer["contours"]["tube"][part]) for part in ("K", "C")}
    uncut = shape(frt(client, ON_ROAD)["contours"]["tube"]["K"])
    for part in ("K", "C"):
        av2, osm = cuts["av2"][part], cuts["osm"][part]
        assert osm.area == pytest.approx(av2.area, rel=0.03), part
        assert shapely.symmetric_difference(av2, osm).area < 0.03 * av2.area, part
    assert cuts["osm"]["K"].area < 0.8 * uncut.area  # the cut cuts


def put_osm(client: TestClient, map_id: str, content: bytes, **params: float):
    return client.put(f"/v1/maps/{map_id}", content=content, headers=XML, params=params)


def error_of(response) -> tuple[str, str]:
    assert response.status_code == 422, response.text
    detail = response.json()["detail"][0]
    return response.json()["field"], detail["msg"]


def test_malformed_osm_is_a_422_naming_what_is_wrong(client: TestClient, osm: bytes) -> None:
    text = osm.decode()
    lane = next(iter(json.loads(RAW)["lane_segments"]))
    missing = text.replace('<way id="1">', '<way id="999999">', 1)
    field, msg = error_of(put_osm(client, "bad", missing.encode()))
    assert field.startswith("relation.") and field.endswith((".member.left", ".member.right"))
    assert msg == "way 1 not found"
    bad_x = text.replace('<tag k="local_x" v="', '<tag k="local_x" v="east', 1)
    field, msg = error_of(put_osm(client, "bad", bad_x.encode()))
    assert field == "node.1.tag.local_x" and msg.startswith("must be a number, got 'east")
    one_bound = text.replace(f'<relation id="{lane}">\n    <member type="way" ref="1" role="left"/>',
                             f'<relation id="{lane}">', 1)  # fmt: skip
    assert error_of(put_osm(client, "bad", one_bound.encode()))[0] == f"relation.{lane}.member.left"
    bomb = (b'<?xml version="1.0"?><!DOCTYPE osm [<!ENTITY a "aaaaaaaaaa">'
            b'<!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;">]><osm>&b;</osm>')  # fmt: skip
    external = b'<?xml version="1.0"?><!DOCTYPE osm [<!ENTITY x SYSTEM "file:///etc/passwd">]><osm>&x;</osm>'
    for content in (bomb, external, b"<osm><node", b"<html></html>", b"<osm></osm>"):
        assert error_of(put_osm(client, "bad", content))[0] == "body", content
    # An XML content type reads XML; a JSON one reads JSON.
    assert error_of(client.put("/v1/maps/bad", content=RAW, headers=XML))[0] == "body"
    json_type = {"content-type": "application/json"}
    assert error_of(client.put("/v1/maps/bad", content=osm, headers=json_type))[0] == "body"
    assert client.get("/v1/maps/bad").status_code == 404


def test_an_oversized_osm_map_is_refused(analytic_model_path: Path, osm: bytes) -> None:
    app = create_app(settings_for(analytic_model_path, max_map_bytes=50_000, max_map_points=200))
    with TestClient(app, raise_server_exceptions=False) as client:
        assert put_osm(client, "big", osm).status_code == 413
        small = osm_of({"lane_segments": {}, "pedestrian_crossings": {},
                        "drivable_areas": json.loads(RAW)["drivable_areas"]})  # fmt: skip
        nodes = small.count(b"<node ")
        assert nodes > 200 and len(small) < 50_000
        field, msg = error_of(put_osm(client, "big", small))
        assert field == "node" and "more than 200 nodes" in msg
        assert client.get("/v1/maps/big").status_code == 404


def test_lat_lon_are_projected_about_the_origin(client: TestClient, archive: dict) -> None:
    origin = (30.27, -97.74)
    lat_lon = osm_of(archive, origin)
    assert b"local_x" not in lat_lon
    body = put_osm(client, "geo", lat_lon, origin_lat=origin[0], origin_lon=origin[1]).json()
    assert body["extent"] == pytest.approx(client.get("/v1/maps/osm").json()["extent"], abs=1e-6)
    # The origin one degree of latitude further south puts the map R·π/180 m (111 319.49 m)
    # further north.
    r = put_osm(client, "geo", lat_lon, origin_lat=origin[0] - 1.0, origin_lon=origin[1])
    shift = r.json()["extent"][1] - body["extent"][1]
    assert shift == pytest.approx(EARTH_RADIUS_M * math.pi / 180.0, rel=1e-9)
    assert error_of(put_osm(client, "geo", lat_lon, origin_lat=1.0)) == (
        "origin_lon",
        "origin_lat and origin_lon go together",
    )
    client.delete("/v1/maps/geo")


def test_frt_map_reads_an_osm_file(analytic_model_path: Path, tmp_path: Path, osm: bytes) -> None:
    path = tmp_path / "austin.osm"
    path.write_bytes(osm)
    app = create_app(settings_for(analytic_model_path, map=path, map_id="austin"))
    with TestClient(app, raise_server_exceptions=False) as client:
        body = client.get("/v1/maps/austin").json()
        assert body["format"] == "lanelet2" and body["source"] == "file"
    assert RoadMap.load(path).format == "lanelet2" and RoadMap.load(ARCHIVE).format == "argoverse2"
    path.write_bytes(osm.replace(b'<way id="2">', b'<way id="999998">', 1))
    with pytest.raises(ValueError, match=r"way 2 not found"):
        create_app(settings_for(analytic_model_path, map=path))


def lanelet_map(left: list, right: list, tags: str = "") -> bytes:
    """A made-up map: lanelets given by their bounds' node lists, nodes 1..n on a 4 m grid."""
    points = {n for line in left + right for n in line}
    nodes = "".join(f'<node id="{n}" lat="0" lon="0"><tag k="local_x" v="{4.0 * (n % 10)}"/>'
                    f'<tag k="local_y" v="{4.0 * (n // 10)}"/></node>' for n in sorted(points))  # fmt: skip
    ways, relations = [], []
    for i, (a, b) in enumerate(zip(left, right, strict=True)):
        for j, line in enumerate((a, b)):
            ways.append(
                f'<way id="{10 * i + j + 1}">'
                + "".join(f'<nd ref="{n}"/>' for n in line)
                + "</way>"
            )
        relations.append(f'<relation id="{i + 1}"><member type="way" ref="{10 * i + 1}" role="left"/>'
                         f'<member type="way" ref="{10 * i + 2}" role="right"/>'
                         f'<tag k="type" v="lanelet"/>{tags}</relation>')  # fmt: skip
    return ("<osm>" + nodes + "".join(ways) + "".join(relations) + "</osm>").encode()


def test_bounds_are_oriented_by_their_sides_and_two_way_lanelets_go_both_ways() -> None:
    # Lanelet 1 drives +x from x=0 to x=4 (left bound y=4, right y=0), lanelet 2 on to x=8 with
    # its right bound drawn backwards: Lanelet2's align turns it round and 2 follows 1.
    road = road_map_from_osm(lanelet_map([[10, 11], [11, 12]], [[0, 1], [2, 1]]))
    lanes = {lane.id: lane for lane in road.lanes}
    assert lanes["1"].successors == ("2",) and lanes["2"].predecessors == ("1",)
    assert np.allclose(lanes["2"].right, [[4.0, 0.0], [8.0, 0.0]])
    # Drawn with its bounds swapped (left at y=0), lanelet 1 drives -x: both bounds turned round.
    swapped = {lane.id: lane for lane in road_map_from_osm(lanelet_map([[0, 1]], [[10, 11]])).lanes}
    assert np.allclose(swapped["1"].left, [[4.0, 0.0], [0.0, 0.0]])
    two_way = road_map_from_osm(lanelet_map([[10, 11]], [[0, 1]], '<tag k="one_way" v="no"/>'))
    ids = {lane.id for lane in two_way.lanes}
    assert ids == {"1", "1" + REVERSE} and two_way.lane_graph.follow == [(), ()]
    with pytest.raises(MapFormatError, match=r"relation\.1\.member\.left: way 1 not found"):
        road_map_from_osm(lanelet_map([[10, 11]], [[0, 1]]).replace(b'way id="1"', b'way id="7"'))


def test_an_area_is_its_outer_ring_less_its_inner_one() -> None:
    grid = "".join(f'<node id="{n}" lat="0" lon="0"><tag k="local_x" v="{x}"/>'
                   f'<tag k="local_y" v="{y}"/></node>'
                   for n, (x, y) in enumerate([(0, 0), (10, 0), (10, 10), (0, 10), (4, 4),
                                               (6, 4), (6, 6), (4, 6)], start=1))  # fmt: skip
    ways = ('<way id="1"><nd ref="1"/><nd ref="2"/><nd ref="3"/></way>'
            '<way id="2"><nd ref="1"/><nd ref="4"/><nd ref="3"/></way>'
            '<way id="3"><nd ref="5"/><nd ref="6"/><nd ref="7"/><nd ref="8"/><nd ref="5"/></way>')  # fmt: skip
    area = ('<relation id="9"><member type="way" ref="1" role="outer"/>'
            '<member type="way" ref="2" role="outer"/><member type="way" ref="3" role="inner"/>'
            '<tag k="type" v="multipolygon"/><tag k="subtype" v="parking"/></relation>')  # fmt: skip
    road = road_map_from_osm(f"<osm>{grid}{ways}{area}</osm>".encode())
    assert road.drivable.area == pytest.approx(100.0 - 4.0) and road.lanes == ()
    open_ring = area.replace('<member type="way" ref="2" role="outer"/>', "")
    with pytest.raises(MapFormatError, match=r"relation\.9\.member\.outer: .*do not close"):
        road_map_from_osm(f"<osm>{grid}{ways}{open_ring}</osm>".encode())
    vegetation = area.replace('v="parking"', 'v="vegetation"')
    with pytest.raises(MapFormatError, match=r"^body: no drivable lanelet or area"):
        road_map_from_osm(f"<osm>{grid}{ways}{vegetation}</osm>".encode())
