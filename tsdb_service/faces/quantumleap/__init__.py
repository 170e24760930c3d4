"""QuantumLeap 1.0's API (``/v2``): history by entity, type and attribute,
the entity list, last values (``op/query``), deletes and the subscription
helper. Parsing is ``params``, rendering ``shape``; answers come from
``history``.

``router`` carries every route; ``openapi.SCHEMAS`` the component schemas.
"""

from __future__ import annotations

from fastapi import APIRouter

from tsdb_service.faces.quantumleap import deletes, entities, history, op_query, subscribe

router = APIRouter()
for _routes in (entities, history, deletes, op_query, subscribe):
    router.include_router(_routes.router)
