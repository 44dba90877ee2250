"""GeoJSON of the contours: every polygon of the set, in order, to the millimetre."""

from __future__ import annotations

import json

import shapely

from reach.geojson import to_geojson


def _round_trip(geojson: dict) -> shapely.Geometry:
    return shapely.from_geojson(json.dumps(geojson))


def test_polygons_with_holes_and_multipolygons_round_trip_to_the_millimetre() -> None:
    ring = shapely.Point(3.0, -1.0).buffer(4.0, quad_segs=8)
    holed = ring.difference(shapely.Point(3.5, -1.0).buffer(1.0))
    multi = shapely.union_all([holed, shapely.box(20.0, 20.0, 21.5, 22.25)])
    for geometry, kind in ((holed, "Polygon"), (multi, "MultiPolygon")):
        out = to_geojson(geometry)
        assert out["type"] == kind
        back = _round_trip(out)
        assert back.symmetric_difference(geometry).area < 1e-3 * geometry.length
        assert shapely.get_num_coordinates(back) == shapely.get_num_coordinates(geometry)


def test_parts_without_area_are_left_out_and_empty_sets_stay_valid() -> None:
    square = shapely.box(0.0, 0.0, 1.0, 1.0)
    collection = shapely.GeometryCollection([square, shapely.LineString([(5, 5), (6, 6)])])
    out = to_geojson(collection)
    assert out["type"] == "MultiPolygon" and len(out["coordinates"]) == 1
    assert _round_trip(out).equals(shapely.MultiPolygon([square]))
    assert to_geojson(shapely.Polygon()) == {"type": "MultiPolygon", "coordinates": []}


def _signed_area(ring: list) -> float:
    """Shoelace: positive for a counter-clockwise ring."""
    xy = list(zip(*ring, strict=True))
    x, y = xy[0], xy[1]
    return 0.5 * sum(x[i] * y[i + 1] - x[i + 1] * y[i] for i in range(len(x) - 1))


def test_rings_follow_the_right_hand_rule() -> None:
    """RFC 7946 3.1.6: exterior rings counter-clockwise, holes clockwise, whatever the input."""
    ring = shapely.Point(0.0, 0.0).buffer(4.0, quad_segs=8)
    holed = ring.difference(shapely.Point(0.5, 0.0).buffer(1.0))
    clockwise = shapely.Polygon(holed.exterior.coords[::-1], [holed.interiors[0].coords[::-1]])
    multi = shapely.MultiPolygon([clockwise, shapely.box(20.0, 20.0, 21.0, 21.0, ccw=False)])
    for geometry in (holed, clockwise, multi):
        out = to_geojson(geometry)
        polygons = [out["coordinates"]] if out["type"] == "Polygon" else out["coordinates"]
        for rings in polygons:
            assert _signed_area(rings[0]) > 0
            assert all(_signed_area(hole) < 0 for hole in rings[1:])
