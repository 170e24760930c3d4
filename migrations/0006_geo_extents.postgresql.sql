-- Where each series has ever been: the bounding box of all its geo samples
-- (tsdb_service/geo/extents.py). A geo-query looks up the series that could
-- ever have been near the queried area here instead of scanning every stored
-- position. The writers grow a row in the transaction that stores the samples
-- (extents only grow: a delete leaves them as they are).
--
-- Upgrading: every replica writing to the database must run a version that
-- maintains this table (samples written by an older one would be missing
-- from the extents and so from geo-query answers).

CREATE TABLE geo_extents (
    sid      INTEGER          PRIMARY KEY,
    min_lon  DOUBLE PRECISION NOT NULL,
    min_lat  DOUBLE PRECISION NOT NULL,
    max_lon  DOUBLE PRECISION NOT NULL,
    max_lat  DOUBLE PRECISION NOT NULL
);

-- The queried area's box overlaps a series' extent: core GiST on box, no PostGIS.
CREATE INDEX geo_extents_box ON geo_extents USING gist (box(point(min_lon, min_lat), point(max_lon, max_lat)));

-- Existing databases: every position stored so far. No writer may commit
-- samples while this reads them (they would be missing from the extents).
LOCK TABLE samples IN SHARE MODE;

INSERT INTO geo_extents (sid, min_lon, min_lat, max_lon, max_lat)
SELECT sid, min(min_lon), min(min_lat), max(max_lon), max(max_lat)
FROM samples WHERE kind = 7 AND geo IS NOT NULL
GROUP BY sid;
