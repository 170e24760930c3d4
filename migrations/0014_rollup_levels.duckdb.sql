-- Rollups kept on ingest, in two levels (issue 38; tsdb_service/storage/rollups.py,
-- docs/long-windows.md "Rollups and retention").
--
-- rollups_minute and rollups_hour hold, per series and UTC minute (hour), the
-- partial aggregate of its samples: how many hold a value (n_present), how
-- many are numbers and integers, their sum, the smallest and largest with the
-- time of the earliest sample holding each (epoch microseconds), and the
-- first and last by (time, row id) with their time and row id. The writer
-- appends the partials of every batch it inserts to rollups_hot (level 1:
-- minute, 2: hour) in the batch's own transaction; the compactor merges hot
-- rows into the two tables. A bucket may be held by several rows at once
-- (merged and hot): readers read the *_all views and combine them. No
-- primary key: the compactor keeps one merged row per bucket, and an index
-- would slow every merge.
--
-- rollups_expired: per series, the newest sample time retention has deleted
-- (a bucket starting after it can be recomputed from raw samples).
--
-- From rollups_hourly (retention's folded hours before this version): its
-- rows become hot hour rows (their raw samples are gone). They know no
-- sample times: their min, max, first and last times are the hour's start,
-- their first and last values unknown. Every stored sample is rolled up by
-- the statements that follow this file (storage.rollups.fill_statements).

CREATE TABLE rollups_minute (
    sid       INTEGER   NOT NULL,
    bucket    TIMESTAMP NOT NULL,  -- the bucket's start, UTC
    n_present BIGINT    NOT NULL,
    n_numeric BIGINT    NOT NULL,
    n_integer BIGINT    NOT NULL,
    num_sum   DOUBLE,
    num_min   DOUBLE,
    min_us    BIGINT,
    num_max   DOUBLE,
    max_us    BIGINT,
    num_first DOUBLE,
    first_us  BIGINT,
    first_rid BIGINT,
    num_last  DOUBLE,
    last_us   BIGINT,
    last_rid  BIGINT
);

CREATE TABLE rollups_hour (
    sid       INTEGER   NOT NULL,
    bucket    TIMESTAMP NOT NULL,
    n_present BIGINT    NOT NULL,
    n_numeric BIGINT    NOT NULL,
    n_integer BIGINT    NOT NULL,
    num_sum   DOUBLE,
    num_min   DOUBLE,
    min_us    BIGINT,
    num_max   DOUBLE,
    max_us    BIGINT,
    num_first DOUBLE,
    first_us  BIGINT,
    first_rid BIGINT,
    num_last  DOUBLE,
    last_us   BIGINT,
    last_rid  BIGINT
);

CREATE TABLE rollups_hot (
    level     UTINYINT  NOT NULL,  -- 1: minute, 2: hour
    sid       INTEGER   NOT NULL,
    bucket    TIMESTAMP NOT NULL,
    n_present BIGINT    NOT NULL,
    n_numeric BIGINT    NOT NULL,
    n_integer BIGINT    NOT NULL,
    num_sum   DOUBLE,
    num_min   DOUBLE,
    min_us    BIGINT,
    num_max   DOUBLE,
    max_us    BIGINT,
    num_first DOUBLE,
    first_us  BIGINT,
    first_rid BIGINT,
    num_last  DOUBLE,
    last_us   BIGINT,
    last_rid  BIGINT
);

CREATE VIEW rollups_minute_all AS
    SELECT * FROM rollups_minute
    UNION ALL
    SELECT sid, bucket, n_present, n_numeric, n_integer, num_sum, num_min, min_us, num_max, max_us,
           num_first, first_us, first_rid, num_last, last_us, last_rid
    FROM rollups_hot WHERE level = 1;

CREATE VIEW rollups_hour_all AS
    SELECT * FROM rollups_hour
    UNION ALL
    SELECT sid, bucket, n_present, n_numeric, n_integer, num_sum, num_min, min_us, num_max, max_us,
           num_first, first_us, first_rid, num_last, last_us, last_rid
    FROM rollups_hot WHERE level = 2;

CREATE TABLE rollups_expired (
    sid  INTEGER   PRIMARY KEY,
    upto TIMESTAMP NOT NULL
);

INSERT INTO rollups_hot
SELECT 2, sid, bucket, n_present, n_numeric, CASE WHEN all_integer THEN n_numeric ELSE 0 END,
       num_sum, num_min, epoch_us(bucket), num_max, epoch_us(bucket), NULL, epoch_us(bucket), 0,
       NULL, epoch_us(bucket), 0
FROM rollups_hourly;

INSERT INTO rollups_expired
SELECT sid, max(bucket) + INTERVAL 1 HOUR - INTERVAL 1 MICROSECOND FROM rollups_hourly GROUP BY sid;

DROP TABLE rollups_hourly;

UPDATE retention_state SET tbl = 'hour' WHERE tbl = 'rollups';
