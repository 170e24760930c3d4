"""The sample columns both backends store, and the exact conversions into them.

The lowest module of ``storage`` besides the vocabulary: the SQL renderers
(``storage.sql``) and both writers read the column names and the helpers
here, so it imports nothing but ``core``. How an attribute fills the value
columns (``content_values``) and how a moment becomes the integer
microseconds the writers stage (``to_micros``, exact where a float division
is not) are written once, here.
"""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

from tsdb_service.core.buckets import epoch_micros
from tsdb_service.core.model import AttrSample

GEO_COLUMNS = ("geo", "lon", "lat", "min_lon", "min_lat", "max_lon", "max_lat")
# What an attribute instance's content fills (a replacement rewrites these).
VALUE_COLUMNS = ("kind", "atype", "num", "txt", "js", *GEO_COLUMNS, "md")
LD_TIME_COLUMNS = ("observed_at", "created_at", "modified_at", "deleted_at")
# Every stored column but the instance id, which each store allocates itself.
SAMPLE_COLUMNS = ("rid", "sid", "t", *VALUE_COLUMNS, *LD_TIME_COLUMNS)
NO_GEO = (None,) * len(GEO_COLUMNS)

EPOCH = datetime(1970, 1, 1, tzinfo=UTC)
ONE_US = timedelta(microseconds=1)


def content_values(a: AttrSample) -> tuple:
    """``VALUE_COLUMNS`` of an attribute sample (the geometry's columns all
    None without one). Not for per-row loops: the COPY and Arrow paths write
    the same order out in place."""
    g = a.geo
    geo = NO_GEO if g is None else (g.geojson, g.lon, g.lat, g.min_lon, g.min_lat, g.max_lon, g.max_lat)
    return (int(a.kind), a.ngsi_type, a.num, a.txt, a.js, *geo, a.md)


to_micros = epoch_micros  # exact microseconds since the epoch (float timestamps lose precision)


def naive_utc(moment: datetime) -> datetime:
    """A timezone-aware moment as the naive UTC timestamp the columns hold."""
    return moment.astimezone(UTC).replace(tzinfo=None)
