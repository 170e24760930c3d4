"""The NGSI-LD temporal API (ETSI GS CIM 009, clauses 5.6.11-5.6.16, 6.18-6.24).

``router`` carries every route (writes, then reads); ``LARGE_BODIES`` the
routes whose bodies may be as large as a notification (``http.bodies``).
"""

from __future__ import annotations

from fastapi import APIRouter

from tsdb_service.faces.ngsild import routes_read, write
from tsdb_service.faces.ngsild.write import LARGE_BODIES

__all__ = ["LARGE_BODIES", "router"]

router = APIRouter()
router.include_router(write.router)
router.include_router(routes_read.router)
