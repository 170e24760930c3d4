-- Core schema for the embedded DuckDB backend.
--
-- Samples are narrow (one row per attribute value) and keyed by a series id
-- that names (tenant, service path, entity, type, attribute). New rows land
-- in samples_hot in arrival order; a compactor moves them to samples sorted
-- by (sid, t), so DuckDB's per-row-group min/max statistics prune a
-- one-series query to a few row groups. There is deliberately no primary key
-- or index on the sample tables: they would slow every insert.

CREATE TABLE series (
    sid          INTEGER PRIMARY KEY,
    tenant       VARCHAR NOT NULL,
    service_path VARCHAR NOT NULL,
    entity_id    VARCHAR NOT NULL,
    entity_type  VARCHAR NOT NULL,
    attr         VARCHAR NOT NULL,
    UNIQUE (tenant, service_path, entity_id, entity_type, attr)
);

CREATE TABLE samples (
    rid      BIGINT    NOT NULL,  -- one per entity per notification: the wide-row key
    sid      INTEGER   NOT NULL,
    t        TIMESTAMP NOT NULL,  -- time index, UTC, microseconds
    kind     UTINYINT  NOT NULL,  -- tsdb_service.model.Kind
    atype    VARCHAR,             -- NGSI type as declared
    num      DOUBLE,
    txt      VARCHAR,
    js       VARCHAR,             -- raw value as JSON text (structured, geo, boolean)
    geo      VARCHAR,             -- normalised GeoJSON, lon/lat order
    lon      DOUBLE,
    lat      DOUBLE,
    min_lon  DOUBLE,
    min_lat  DOUBLE,
    max_lon  DOUBLE,
    max_lat  DOUBLE,
    md       VARCHAR              -- metadata as JSON text
);

CREATE TABLE samples_hot AS SELECT * FROM samples WITH NO DATA;

CREATE VIEW samples_all AS
    SELECT * FROM samples
    UNION ALL
    SELECT * FROM samples_hot;

CREATE TABLE rejected_notifications (
    id          BIGINT    NOT NULL,
    tenant      VARCHAR   NOT NULL,
    received_at TIMESTAMP NOT NULL,
    error       VARCHAR   NOT NULL,
    description VARCHAR   NOT NULL,
    headers     VARCHAR   NOT NULL,
    body        BLOB      NOT NULL
);

-- Attribute layouts for Orion's "values" notification format, which carries
-- values without names: we must know the subscription's attribute list.
CREATE TABLE subscriptions (
    tenant          VARCHAR NOT NULL,
    subscription_id VARCHAR NOT NULL,
    attrs           VARCHAR NOT NULL,  -- JSON array of attribute names
    entity_id       VARCHAR,
    entity_type     VARCHAR,
    registered_at   TIMESTAMP NOT NULL,
    PRIMARY KEY (tenant, subscription_id)
);
