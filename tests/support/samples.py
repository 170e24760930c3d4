"""Numbered samples for the storage tests: entity ``n`` of a run of
``count``, one numeric attribute each of ``attrs`` with value ``n``, one
millisecond apart, over ``series`` entity ids taken in turn."""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime, timedelta

from tsdb_service.core.model import AttrSample, EntitySample, Kind


def numbered(
    tenant: str,
    entity_type: str,
    attrs: Sequence[str],
    start: datetime,
    count: int,
    *,
    first: int = 0,
    series: int = 20,
) -> list[EntitySample]:
    return [
        EntitySample(
            tenant,
            "/",
            f"urn:ngsi-ld:{entity_type}:{n % series}",
            entity_type,
            start + timedelta(milliseconds=n),
            [AttrSample(name, "Number", Kind.NUMBER, num=float(n)) for name in attrs],
        )
        for n in range(first, first + count)
    ]
