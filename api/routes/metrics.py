"""``GET /metrics``: the service in Prometheus' text format (``api.metrics``). Behind the token
like ``/v1`` (Prometheus sends it: ``authorization: {credentials: ...}``; a read-role token will do)."""

from __future__ import annotations

from fastapi import APIRouter, Request, Response
from prometheus_client import CONTENT_TYPE_LATEST

from ..deps import Authorized
from ..downloads import file_response
from ..errors import documented

router = APIRouter(tags=["metrics"], dependencies=[Authorized],
                   responses=documented({401: "missing or invalid bearer token"}))


@router.get("/metrics", response_class=Response, responses=file_response("the metrics", CONTENT_TYPE_LATEST))
def metrics(request: Request) -> Response:
    return Response(request.app.state.metrics.render(), media_type=CONTENT_TYPE_LATEST)
