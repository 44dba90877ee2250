"""GeoJSON of the contours: every polygon of the set, in order, to the millimetre."""

from __future__ import annotations

import json

import shapely

from service.engine import _geojson


def _round_trip(geojson: dict) -> shapely.Geometry:
    return shapely.from_geojson(json.dumps(geojson))


def test_polygons_with_holes_and_multipolygons_round_trip_to_the_millimetre() -> None:
    ring = shapely.Point(3.0, -1.0).buffer(4.0, quad_segs=8)
    holed = ring.difference(shapely.Point(3.5, -1.0).buffer(1.0))
    multi = shapely.union_all([holed, shapely.box(20.0, 20.0, 21.5, 22.25)])
    for geometry, kind in ((holed, "Polygon"), (multi, "MultiPolygon")):
        out = _geojson(geometry)
        assert out["type"] == kind
        back = _round_trip(out)
        assert back.symmetric_difference(geometry).area < 1e-3 * geometry.length
        assert shapely.get_num_coordinates(back) == shapely.get_num_coordinates(geometry)


def test_parts_without_area_are_left_out_and_empty_sets_stay_valid() -> None:
    square = shapely.box(0.0, 0.0, 1.0, 1.0)
    collection = shapely.GeometryCollection([square, shapely.LineString([(5, 5), (6, 6)])])
    out = _geojson(collection)
    assert out["type"] == "MultiPolygon" and len(out["coordinates"]) == 1
    assert _round_trip(out).equals(shapely.MultiPolygon([square]))
    assert _geojson(shapely.Polygon()) == {"type": "MultiPolygon", "coordinates": []}
