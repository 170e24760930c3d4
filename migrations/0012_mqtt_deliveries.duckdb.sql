-- MQTT notifications (issue 31; ingest.mqtt, docs/mqtt.md).
--
-- mqtt_deliveries: the identity of each MQTT message this service stored or
-- kept as rejected, written in the same transaction as its samples or its
-- rejected row (on DuckDB through the ingest log, in the same record). A
-- broker resends a message it has no PUBACK for with its DUP flag and its
-- packet id; the consumer drops such a redelivery when (packet_id, digest)
-- is among the newest deliveries of its client id, so a message stored
-- before a crash, and acknowledged only after, is not stored twice.
--   client_id    the MQTT client id (one per replica; the broker's session)
--   seq          the consumer's count of its messages, in arrival order
--   packet_id    the MQTT packet identifier the broker gave the message
--   digest       BLAKE2b-128 of the topic, a NUL and the payload
--   received_at  UTC
-- The consumer keeps a few times its receive maximum of rows per client id
-- and deletes older ones as it goes.
--
-- rejected_notifications.topic: the MQTT topic of a message kept in the
-- rejected store (NULL for HTTP notifications).

CREATE TABLE mqtt_deliveries (
    client_id   VARCHAR   NOT NULL,
    seq         BIGINT    NOT NULL,
    packet_id   INTEGER   NOT NULL,
    digest      BLOB      NOT NULL,
    received_at TIMESTAMP NOT NULL,
    PRIMARY KEY (client_id, seq)
);

ALTER TABLE rejected_notifications ADD COLUMN topic VARCHAR;
