-- Rejected notifications keep what an operator needs to recover them:
-- body_size is the size of the body as received (the Content-Length, or the
-- bytes counted), body_truncated says that only the first bytes of a body
-- over the limit are stored (up to TSDB_REJECTED_BODY_MAX_BYTES). The tenant
-- column holds the tenant header as received when the API refuses it, so an
-- operator listing across tenants still finds the notification.

ALTER TABLE rejected_notifications ADD COLUMN body_size BIGINT;

ALTER TABLE rejected_notifications ADD COLUMN body_truncated BOOLEAN DEFAULT false;

UPDATE rejected_notifications SET body_size = octet_length(body), body_truncated = false;
