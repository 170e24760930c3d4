-- tsdb-service copy: one row per copy into this store, so an interrupted
-- copy is recognised and resumed instead of duplicated or mistaken for data.
--
-- Samples are copied in batches, each committed alone and in source row-id
-- order, so the target always holds a prefix of the source: a resumed copy
-- skips as many source samples as the target gained since base_counts.
CREATE TABLE IF NOT EXISTS copy_runs (
    source         VARCHAR NOT NULL,   -- DuckDB file (absolute) or URL without its password
    started_at     TIMESTAMP NOT NULL, -- UTC
    finished_at    TIMESTAMP,          -- UTC; NULL while running or after an interruption
    base_counts    VARCHAR NOT NULL,   -- JSON {tenant: samples} in this store before the copy
    base_rejected  BIGINT NOT NULL,    -- rejected notifications in this store before the copy
    source_samples BIGINT NOT NULL     -- samples in the source when the copy started
);
