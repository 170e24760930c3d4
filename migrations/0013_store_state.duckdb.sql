-- The database's identity and how much of its ingest log it holds (issue 37;
-- write.logged, write.log, docs/architecture.md "The write path").
--
-- store_state has one row:
--   database_id      names this database: every ingest-log segment carries it,
--                    and a log naming another database is never replayed here;
--                    a restored backup gets a new one (tsdb-service restore)
--   log_applied_seq  the last ingest-log record applied to this database,
--   log_applied_rid  and the largest row id applied: both move in the same
--                    transaction as the samples of each applied batch, so a
--                    replay applies exactly the records past them, whatever
--                    deletes, instance edits and retention removed since
--   log_legacy       the log may still hold segments written before they had
--                    a header (no identity): replayed once after this upgrade,
--                    refused once none is left
--
-- A database from before this migration held every record up to its largest
-- row id (the rule of the time): that is where its position starts.

CREATE TABLE store_state (
    database_id     UUID    NOT NULL,
    log_applied_seq BIGINT  NOT NULL,
    log_applied_rid BIGINT  NOT NULL,
    log_legacy      BOOLEAN NOT NULL
);

INSERT INTO store_state
SELECT uuid(), 0,
       greatest(coalesce((SELECT max(rid) FROM samples), 0), coalesce((SELECT max(rid) FROM samples_hot), 0)),
       true;
