"""NGSI notifications (NGSIv2, NGSIv1 legacy, NGSI-LD) → ingest model."""

from tsdb_service.parse.notification import ValuesLayout, load_document, parse_document, parse_notification

__all__ = ["ValuesLayout", "load_document", "parse_document", "parse_notification"]
