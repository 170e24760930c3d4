"""What an entity's extent settles without reading its positions.

``GeoFilter.classify_extents`` says, for the bounding box of every position
an entity ever had, whether all of them surely match or none can. A wrong
"surely" would return or drop samples silently, so here every verdict is
checked against the exact predicate on many points and shapes inside each
box, for every georel, near the thresholds, at several latitudes.
"""

from __future__ import annotations

import math
import random

import numpy as np
import orjson
import pytest

from tsdb_service.geo.filter import parse_geo

QUERIES = [
    ("near;maxDistance:1000", "point", "{lat},{lon}"),
    ("near;maxDistance:2500", "point", "{lat},{lon}"),
    ("near;minDistance:800", "point", "{lat},{lon}"),
    ("near;minDistance:500;maxDistance:1200", "point", "{lat},{lon}"),
    ("coveredBy", "box", "{lat0},{lon0};{lat1},{lon1}"),
    ("intersects", "polygon", "{lat0},{lon0};{lat0},{lon1};{lat1},{lon1};{lat0},{lon0}"),
    ("disjoint", "box", "{lat0},{lon0};{lat1},{lon1}"),
    ("equals", "point", "{lat},{lon}"),
]


def _inside(rnd: random.Random, box) -> list[str]:
    """GeoJSON points and short lines inside ``box``, corners included."""
    lon0, lat0, lon1, lat1 = box
    points = [(lon0, lat0), (lon1, lat1), (lon0, lat1), (lon1, lat0)]
    points += [(rnd.uniform(lon0, lon1), rnd.uniform(lat0, lat1)) for _ in range(30)]
    shapes = [{"type": "Point", "coordinates": list(p)} for p in points]
    shapes += [{"type": "LineString", "coordinates": [list(points[i]), list(points[i + 1])]} for i in range(0, 8, 2)]
    return [orjson.dumps(s).decode() for s in shapes]


@pytest.mark.parametrize("lat", [0.0, 40.4, 60.2, 84.0])
@pytest.mark.parametrize(("georel", "geometry", "coords"), QUERIES)
def test_verdicts_hold_for_every_position_inside(lat, georel, geometry, coords):
    rnd = random.Random(f"{lat}{georel}")
    lon = 10.0
    stretch = 1 / math.cos(math.radians(lat))  # the same metres east-west at every latitude
    query = coords.format(
        lat=lat, lon=lon, lat0=lat - 0.005, lon0=lon - 0.007 * stretch, lat1=lat + 0.006, lon1=lon + 0.008 * stretch
    )
    geo = parse_geo(georel, geometry, query)
    boxes = []
    for _ in range(300):  # boxes of 0..0.02°: small and not, straddling the thresholds
        w, h = rnd.choice([0.0, 0.0005, 0.002, 0.012]) * rnd.random(), rnd.choice([0.0, 0.001, 0.02]) * rnd.random()
        cx, cy = lon + rnd.uniform(-0.03, 0.03) * stretch, lat + rnd.uniform(-0.03, 0.03)
        boxes.append((cx, cy, cx + w, cy + h))
    every, none = geo.classify_extents(np.array(boxes))
    assert none.any() and (every.any() or georel == "equals"), "the cases must exercise the verdicts"
    assert not (every & none).any()
    for box, all_match, no_match in zip(boxes, every, none, strict=True):
        if not (all_match or no_match):
            continue
        texts = np.array(_inside(rnd, box), dtype=object)
        matched = geo.matches_array(np.zeros(len(texts)), np.zeros(len(texts)), texts, np.zeros(len(texts), bool))
        assert matched.all() if all_match else not matched.any(), (box, all_match)
