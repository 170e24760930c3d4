-- Rollups kept on ingest, in two levels (issue 38; tsdb_service/storage/rollups.py,
-- docs/long-windows.md "Rollups and retention").
--
-- rollups_minute and rollups_hour hold, per series and UTC minute (hour), the
-- partial aggregate of its samples: how many hold a value (n_present), how
-- many are numbers and integers, their sum, the smallest and largest with the
-- time of the earliest sample holding each (epoch microseconds), and the
-- first and last by (time, row id) with their time and row id. The writer
-- appends the partials of every batch it inserts to rollups_hot (level 1:
-- minute, 2: hour) in the inserting statement's transaction: the trigger
-- rollups_fold below, on every INSERT into samples whoever runs it (this
-- service's writers, another replica, tsdb-service copy, SQL by hand). A
-- merger (one replica at a time, under an advisory lock) moves hot rows into
-- the two tables. A bucket may be held by several rows at once (merged and
-- hot): readers read the *_all views and combine them. Its function body is
-- storage.rollups.fold_sql(PostgresDialect(), 'changed'), word for word
-- (tests/test_rollups_replicas.py checks it): change both together, in a new
-- migration.
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
    num_sum   DOUBLE PRECISION,
    num_min   DOUBLE PRECISION,
    min_us    BIGINT,
    num_max   DOUBLE PRECISION,
    max_us    BIGINT,
    num_first DOUBLE PRECISION,
    first_us  BIGINT,
    first_rid BIGINT,
    num_last  DOUBLE PRECISION,
    last_us   BIGINT,
    last_rid  BIGINT
);

CREATE TABLE rollups_hour (
    sid       INTEGER   NOT NULL,
    bucket    TIMESTAMP NOT NULL,
    n_present BIGINT    NOT NULL,
    n_numeric BIGINT    NOT NULL,
    n_integer BIGINT    NOT NULL,
    num_sum   DOUBLE PRECISION,
    num_min   DOUBLE PRECISION,
    min_us    BIGINT,
    num_max   DOUBLE PRECISION,
    max_us    BIGINT,
    num_first DOUBLE PRECISION,
    first_us  BIGINT,
    first_rid BIGINT,
    num_last  DOUBLE PRECISION,
    last_us   BIGINT,
    last_rid  BIGINT
);

CREATE TABLE rollups_hot (
    level     SMALLINT  NOT NULL,  -- 1: minute, 2: hour
    sid       INTEGER   NOT NULL,
    bucket    TIMESTAMP NOT NULL,
    n_present BIGINT    NOT NULL,
    n_numeric BIGINT    NOT NULL,
    n_integer BIGINT    NOT NULL,
    num_sum   DOUBLE PRECISION,
    num_min   DOUBLE PRECISION,
    min_us    BIGINT,
    num_max   DOUBLE PRECISION,
    max_us    BIGINT,
    num_first DOUBLE PRECISION,
    first_us  BIGINT,
    first_rid BIGINT,
    num_last  DOUBLE PRECISION,
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

ALTER TABLE rollups_minute ADD PRIMARY KEY (sid, bucket);
ALTER TABLE rollups_hour ADD PRIMARY KEY (sid, bucket);
CREATE INDEX rollups_hot_sid_bucket ON rollups_hot (sid, bucket);

-- No writer may commit samples until this migration has created the trigger
-- and rolled up every stored sample (in its transaction, after this file).
LOCK TABLE samples IN SHARE MODE;

INSERT INTO rollups_hot
SELECT 2, sid, bucket, n_present, n_numeric, CASE WHEN all_integer THEN n_numeric ELSE 0 END,
       num_sum, num_min, (extract(epoch FROM bucket) * 1000000)::bigint, num_max,
       (extract(epoch FROM bucket) * 1000000)::bigint, NULL, (extract(epoch FROM bucket) * 1000000)::bigint, 0,
       NULL, (extract(epoch FROM bucket) * 1000000)::bigint, 0
FROM rollups_hourly;

INSERT INTO rollups_expired
SELECT sid, max(bucket) + INTERVAL '1 hour' - INTERVAL '1 microsecond' FROM rollups_hourly GROUP BY sid;

DROP TABLE rollups_hourly;

UPDATE retention_state SET tbl = 'hour' WHERE tbl = 'rollups';

CREATE FUNCTION rollups_fold() RETURNS trigger LANGUAGE plpgsql AS $$
BEGIN
    INSERT INTO rollups_hot (level, sid, bucket, n_present, n_numeric, n_integer, num_sum, num_min,
        min_us, num_max, max_us, num_first, first_us, first_rid, num_last, last_us, last_rid) WITH m
        AS MATERIALIZED (SELECT sid, bucket, CAST(count(*) FILTER (WHERE kind <> 0) AS BIGINT) AS
        n_present, CAST(count(v) AS BIGINT) AS n_numeric, CAST(count(v) FILTER (WHERE kind = 2) AS
        BIGINT) AS n_integer, sum(v) AS num_sum, min(v) AS num_min, ((min(ARRAY[v, tu::float8])
        FILTER (WHERE v IS NOT NULL))[2])::bigint AS min_us, max(v) AS num_max, (-(max(ARRAY[v,
        (-tu)::float8]) FILTER (WHERE v IS NOT NULL))[2])::bigint AS max_us, (min(ARRAY[tu::float8,
        rid::float8, v::float8]) FILTER (WHERE v IS NOT NULL))[3] AS num_first, min(tu) FILTER
        (WHERE v IS NOT NULL) AS first_us, ((min(ARRAY[tu::float8, rid::float8, rid::float8]) FILTER
        (WHERE v IS NOT NULL))[3])::bigint AS first_rid, (max(ARRAY[tu::float8, rid::float8,
        v::float8]) FILTER (WHERE v IS NOT NULL))[3] AS num_last, max(tu) FILTER (WHERE v IS NOT
        NULL) AS last_us, ((max(ARRAY[tu::float8, rid::float8, rid::float8]) FILTER (WHERE v IS NOT
        NULL))[3])::bigint AS last_rid FROM (SELECT sid, rid, kind, date_trunc('minute', t) AS
        bucket, CASE WHEN t >= TIMESTAMP '1902-01-01 00:00:00' AND t < TIMESTAMP '2038-01-01
        00:00:00' THEN (date_part('epoch', t) * 1000000)::bigint ELSE (extract(epoch from t) *
        1000000)::bigint END AS tu, CASE WHEN kind IN (1, 2) THEN num END AS v FROM changed OFFSET
        0) AS s GROUP BY sid, bucket) SELECT 1, sid, bucket, n_present, n_numeric, n_integer,
        num_sum, num_min, min_us, num_max, max_us, num_first, first_us, first_rid, num_last,
        last_us, last_rid FROM m UNION ALL SELECT 2, sid, bucket, n_present, n_numeric, n_integer,
        num_sum, num_min, min_us, num_max, max_us, num_first, first_us, first_rid, num_last,
        last_us, last_rid FROM (SELECT sid, date_trunc('hour', bucket) AS bucket,
        CAST(sum(n_present) AS BIGINT) AS n_present, CAST(sum(n_numeric) AS BIGINT) AS n_numeric,
        CAST(sum(n_integer) AS BIGINT) AS n_integer, sum(num_sum) AS num_sum, min(num_min) AS
        num_min, ((min(ARRAY[num_min, min_us::float8]) FILTER (WHERE num_min IS NOT
        NULL))[2])::bigint AS min_us, max(num_max) AS num_max, (-(max(ARRAY[num_max,
        (-max_us)::float8]) FILTER (WHERE num_min IS NOT NULL))[2])::bigint AS max_us,
        (min(ARRAY[first_us::float8, first_rid::float8, num_first::float8]) FILTER (WHERE num_first
        IS NOT NULL))[3] AS num_first, min(first_us) FILTER (WHERE num_first IS NOT NULL) AS
        first_us, ((min(ARRAY[first_us::float8, first_rid::float8, first_rid::float8]) FILTER (WHERE
        num_first IS NOT NULL))[3])::bigint AS first_rid, (max(ARRAY[last_us::float8,
        last_rid::float8, num_last::float8]) FILTER (WHERE num_last IS NOT NULL))[3] AS num_last,
        max(last_us) FILTER (WHERE num_last IS NOT NULL) AS last_us, ((max(ARRAY[last_us::float8,
        last_rid::float8, last_rid::float8]) FILTER (WHERE num_last IS NOT NULL))[3])::bigint AS
        last_rid FROM m AS p GROUP BY sid, date_trunc('hour', bucket)) AS h;
    RETURN NULL;
END
$$;

CREATE TRIGGER rollups_fold AFTER INSERT ON samples
    REFERENCING NEW TABLE AS changed
    FOR EACH STATEMENT EXECUTE FUNCTION rollups_fold();
