"""GeoJSON (RFC 7946) of shapely geometries: the contours the API answers with."""

from __future__ import annotations

import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry
from shapely.geometry.polygon import orient


def to_geojson(geometry: BaseGeometry) -> dict:
    """A GeoJSON Polygon or MultiPolygon of the geometry's polygons, coordinates rounded to the
    millimetre (each ring rounded and listed by numpy, not number by number in Python). Parts of
    lower dimension (a line or point where an intersection degenerates) have no area and are left
    out."""
    polygons: list[shapely.Polygon] = []
    pending = [geometry]
    while pending:
        part = pending.pop()
        if isinstance(part, shapely.Polygon):
            if not part.is_empty:
                polygons.append(part)
        elif isinstance(part, shapely.MultiPolygon | shapely.GeometryCollection):
            pending.extend(reversed(shapely.get_parts(part).tolist()))

    def rings(polygon: shapely.Polygon) -> list:
        polygon = orient(polygon, sign=1.0)  # RFC 7946: exterior counter-clockwise, holes clockwise
        return [
            np.round(shapely.get_coordinates(ring), 3).tolist()
            for ring in (polygon.exterior, *polygon.interiors)
        ]

    if len(polygons) == 1 and isinstance(geometry, shapely.Polygon):
        return {"type": "Polygon", "coordinates": rings(polygons[0])}
    return {"type": "MultiPolygon", "coordinates": [rings(p) for p in polygons]}
