-- The series that hold instances without an observedAt (NGSIv2 samples,
-- NGSI-LD attributes sent without one). An NGSI-LD window on observedAt
-- reads those instances by their row time, through a second index scan of
-- (sid, t) for every selected series (storage.temporal.window_filter);
-- over the 1,900 series of a geo-query that scan costs as much as the one
-- that finds the instances with an observedAt. With this list a read
-- scans (sid, t) only for the series in it: none, for NGSI-LD data that
-- carries observedAt.
--
-- The writers add a series here in the transaction that stores its first
-- such instance (storage.postgres.untimed); deleting samples leaves it here
-- (an entry without such instances only costs that second scan).
--
-- Upgrading: every replica writing to the database must run a version that
-- maintains this table (instances written by an older one without
-- observedAt would be missing from NGSI-LD windows).

CREATE TABLE untimed_series (
    sid INTEGER PRIMARY KEY
);

-- Existing databases: every series stored so far with such an instance. No
-- writer may commit samples while this reads them.
LOCK TABLE samples IN SHARE MODE;

INSERT INTO untimed_series (sid)
SELECT DISTINCT sid FROM samples WHERE observed_at IS NULL;
