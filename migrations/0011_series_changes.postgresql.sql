-- Change counts of the series, so a process may answer aggregations from
-- hourly partials it keeps in memory (storage.partials) although other
-- replicas, other sessions and plain SQL write the same series.
--
-- Series are counted in blocks of eight consecutive ids (``block`` = sid
-- >> 3): the sum of ``n`` over a block's rows grows by at least one with
-- every committed statement that inserted, updated or deleted samples of a
-- series in it. The triggers below add to it in that statement's
-- transaction, whatever wrote it (the writers' COPY, NGSI-LD instance
-- edits, deletes, retention, commands.copy, a bulk load by hand). A reader
-- that finds the sum it saw when it loaded a series' partials knows
-- nothing of the block changed since (storage.postgres.querier,
-- ``_series_versions``). Rows are never decremented; a rolled-back write
-- rolls its increment back with it. Why blocks: one entity's attributes
-- are created together (consecutive ids), so a notification moves one
-- row, not five; counted per series, the trigger cost 0.55 ms on a
-- 150-series COPY, against 0.15 ms by block.
--
-- One row per block and database session (its backend pid), as in
-- series_generation (migration 0010): a writer session only moves its own
-- rows, so the three writer connections of a process, and other replicas',
-- never wait for each other here (with one row per block, every
-- transaction writing a block would wait for the previous one's commit).
-- Rows of sessions that ended are folded into pid 0 when a store opens
-- (``fold_series_changes``), which keeps every sum.
--
-- Blocks with no row have sum 0: data stored before this migration. The
-- counting is the database's, so writers of any version are counted once
-- the database is migrated. A TRUNCATE of samples cannot name its series:
-- it adds to the row of block -1, which readers check with every series.

CREATE TABLE series_changes (
    block INTEGER NOT NULL,  -- sid >> 3; -1: TRUNCATE
    pid   INTEGER NOT NULL,
    n     BIGINT  NOT NULL,
    PRIMARY KEY (block, pid)
) WITH (fillfactor = 70);

CREATE FUNCTION series_changes_bump() RETURNS trigger LANGUAGE plpgsql AS $$
BEGIN
    -- In block order: whoever else ever moves these rows (a fold) locks
    -- them in the same order.
    INSERT INTO series_changes AS c (block, pid, n)
    SELECT DISTINCT sid >> 3, pg_backend_pid(), 1 FROM changed ORDER BY 1
    ON CONFLICT (block, pid) DO UPDATE SET n = c.n + 1;
    RETURN NULL;
END
$$;

CREATE TRIGGER series_changes_insert AFTER INSERT ON samples
    REFERENCING NEW TABLE AS changed
    FOR EACH STATEMENT EXECUTE FUNCTION series_changes_bump();

CREATE TRIGGER series_changes_update AFTER UPDATE ON samples
    REFERENCING NEW TABLE AS changed
    FOR EACH STATEMENT EXECUTE FUNCTION series_changes_bump();

CREATE TRIGGER series_changes_delete AFTER DELETE ON samples
    REFERENCING OLD TABLE AS changed
    FOR EACH STATEMENT EXECUTE FUNCTION series_changes_bump();

CREATE FUNCTION series_changes_truncated() RETURNS trigger LANGUAGE plpgsql AS $$
BEGIN
    INSERT INTO series_changes AS c (block, pid, n) VALUES (-1, pg_backend_pid(), 1)
    ON CONFLICT (block, pid) DO UPDATE SET n = c.n + 1;
    RETURN NULL;
END
$$;

CREATE TRIGGER series_changes_truncate AFTER TRUNCATE ON samples
    FOR EACH STATEMENT EXECUTE FUNCTION series_changes_truncated();
