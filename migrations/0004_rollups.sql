-- Retention and rollups (tsdb_service/storage/retention.py, rollups.py).
--
-- rollups_hourly holds, per series and UTC hour, what the aggregation
-- queries need to answer count/sum/avg/min/max for the samples retention
-- deleted: each retention batch folds the rows it deletes into this table
-- in the same transaction, so every sample is either a raw row or counted
-- here, never both and never neither. The columns are the partials the raw
-- aggregation computes (storage/sql.py, SqlQuerier.aggregate):
-- n_present counts samples with a value, n_numeric the numeric ones,
-- num_sum/num_min/num_max aggregate those, all_integer says they were all
-- integers (NULL when there were none).

CREATE TABLE rollups_hourly (
    sid         INTEGER          NOT NULL,
    bucket      TIMESTAMP        NOT NULL,  -- start of the hour, UTC
    n_present   BIGINT           NOT NULL,
    n_numeric   BIGINT           NOT NULL,
    num_sum     DOUBLE PRECISION,
    num_min     DOUBLE PRECISION,
    num_max     DOUBLE PRECISION,
    all_integer BOOLEAN,
    PRIMARY KEY (sid, bucket)
);

-- The watermark of each retention rule, per table ('samples' or
-- 'rollups'): every row of that rule older than horizon has been deleted
-- (and, with rollups, folded). Kept across restarts for the lag metric.
CREATE TABLE retention_state (
    tbl        VARCHAR   NOT NULL,
    rule       VARCHAR   NOT NULL,
    horizon    TIMESTAMP NOT NULL,
    updated_at TIMESTAMP NOT NULL,
    PRIMARY KEY (tbl, rule)
);
