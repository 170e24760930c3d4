"""NGSI notifications (NGSIv2, NGSIv1 legacy, NGSI-LD) → ingest model."""

from tsdb_service.parse.notification import ValuesLayout, parse_notification

__all__ = ["ValuesLayout", "parse_notification"]
