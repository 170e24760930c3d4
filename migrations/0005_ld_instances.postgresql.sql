-- NGSI-LD attribute instances (issue 13); see 0005_ld_instances.duckdb.sql
-- for the meaning of each column. Here the instance id comes from a
-- sequence shared by every replica (the column default, so COPY omits it);
-- existing samples get theirs now. It is filled before the default is set,
-- which also works on a TimescaleDB hypertable.

ALTER TABLE series ADD COLUMN dataset_id TEXT;

CREATE SEQUENCE sample_iid_seq;
ALTER TABLE samples ADD COLUMN iid BIGINT;
ALTER TABLE samples ADD COLUMN observed_at TIMESTAMP;
ALTER TABLE samples ADD COLUMN created_at TIMESTAMP;
ALTER TABLE samples ADD COLUMN modified_at TIMESTAMP;
ALTER TABLE samples ADD COLUMN deleted_at TIMESTAMP;
UPDATE samples SET iid = nextval('sample_iid_seq');
ALTER TABLE samples ALTER COLUMN iid SET DEFAULT nextval('sample_iid_seq');
ALTER TABLE samples ALTER COLUMN iid SET NOT NULL;

CREATE OR REPLACE VIEW samples_all AS SELECT * FROM samples;
