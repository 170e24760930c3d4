"""Routes served ahead of the framework: the hottest reads, answered exactly
as the framework would answer them, without its cost.

FastAPI's middleware stack and router (some 70 routes tried in turn) cost
more per request than the answer to ``lastN=100`` from memory. The routes
named here are matched with the framework's own matcher (``Route.matches``)
and served by their own endpoints, inside the same read budget
(``http.budget``), with the same error answers (``http.errors``) and the
same route label for the request metrics; the security guard runs before
either way. Anything else, a ``HEAD`` included, goes through the framework.
"""

from __future__ import annotations

from collections.abc import Iterable

from fastapi.routing import APIRoute
from starlette.requests import ClientDisconnect, Request
from starlette.routing import Match
from starlette.types import ASGIApp, Receive, Scope, Send

from tsdb_service.core.budget import ReadLimits, ReadPool
from tsdb_service.core.errors import TsdbError
from tsdb_service.http.budget import ReadBudgetMiddleware
from tsdb_service.http.errors import client_disconnected, error_response, unexpected_response


class FastRoutes:
    def __init__(
        self, routes: Iterable[object], paths: Iterable[str], limits: ReadLimits, pool: ReadPool | None = None
    ):
        wanted = set(paths)
        self._routes = [
            r for r in routes if isinstance(r, APIRoute) and r.path in wanted and "GET" in (r.methods or ())
        ]
        self._budgeted: ASGIApp = ReadBudgetMiddleware(self._serve, limits, pool)

    def match(self, scope: Scope) -> Scope | None:
        """The matched route's child scope (path parameters, route), or None."""
        if scope["type"] != "http" or scope["method"] != "GET":
            return None
        for route in self._routes:
            found, child = route.matches(scope)
            if found is Match.FULL:
                return child
        return None

    async def serve(self, app: ASGIApp, scope: Scope, receive: Receive, send: Send, child: Scope) -> None:
        scope.update(child)
        scope["app"] = app
        await self._budgeted(scope, receive, send)

    @staticmethod
    async def _serve(scope: Scope, receive: Receive, send: Send) -> None:
        request = Request(scope, receive)
        try:
            response = await scope["endpoint"](request)
        except TsdbError as exc:
            response = error_response(request, exc)
        except ClientDisconnect:
            response = client_disconnected(request)
        except Exception as exc:
            response = unexpected_response(request, exc)
        await response(scope, receive, send)
