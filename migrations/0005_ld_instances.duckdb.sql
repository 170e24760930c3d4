-- NGSI-LD attribute instances (issue 13). The time index t stays the
-- NGSIv2/QuantumLeap row time; each sample also keeps what NGSI-LD says
-- about that one instance:
--   iid          a unique 64-bit instance id, allocated by the writer and
--                copied as is by compaction, so the instanceId built from it
--                (urn:ngsi-ld:attribute:instance:<iid>) never changes;
--   observed_at  the instance's own observedAt (NULL: not sent; NGSI-LD
--                reads then fall back to t);
--   created_at, modified_at  as sent by the broker (sysAttrs), or set by
--                the temporal write endpoints;
--   deleted_at   set on deletion instances (value urn:ngsi-ld:null).
-- A non-default datasetId is its own series, named attr~datasetId for the
-- NGSIv2 API; series.dataset_id says which datasetId it is (NULL: default).

ALTER TABLE series ADD COLUMN dataset_id VARCHAR;

ALTER TABLE samples ADD COLUMN iid BIGINT;
ALTER TABLE samples ADD COLUMN observed_at TIMESTAMP;
ALTER TABLE samples ADD COLUMN created_at TIMESTAMP;
ALTER TABLE samples ADD COLUMN modified_at TIMESTAMP;
ALTER TABLE samples ADD COLUMN deleted_at TIMESTAMP;

ALTER TABLE samples_hot ADD COLUMN iid BIGINT;
ALTER TABLE samples_hot ADD COLUMN observed_at TIMESTAMP;
ALTER TABLE samples_hot ADD COLUMN created_at TIMESTAMP;
ALTER TABLE samples_hot ADD COLUMN modified_at TIMESTAMP;
ALTER TABLE samples_hot ADD COLUMN deleted_at TIMESTAMP;

-- Samples stored before this migration get their instance ids now.
CREATE SEQUENCE sample_iid_backfill;
UPDATE samples SET iid = nextval('sample_iid_backfill');
UPDATE samples_hot SET iid = nextval('sample_iid_backfill');
DROP SEQUENCE sample_iid_backfill;

DROP VIEW samples_all;
CREATE VIEW samples_all AS
    SELECT * FROM samples
    UNION ALL
    SELECT * FROM samples_hot;
