"""Every error leaves the service as JSON ``{"detail": ...}``, never as a traceback.

Storage errors map to HTTP statuses (``NotFoundError`` 404, ``ConflictError`` 409,
``InvalidRecordError``/``InvalidKeyError`` 422, ``CorruptArtifactError`` 507: a stored artifact —
checkpoint, cached dataset, plan file — whose bytes no longer match their recorded SHA-256, a status of
its own so a client can say "restore it from a backup" rather than "the service failed"); an invalid
job spec is 422 with a detail naming each field; anything unexpected is 500 with a generic detail,
its traceback logged.
"""

from __future__ import annotations

import logging

from fastapi import FastAPI, Request, status
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.exception_handlers import http_exception_handler
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import Match

from neuenh_service.orchestrator.spec import SpecError
from neuenh_service.storage import (ConflictError, CorruptArtifactError, InvalidKeyError, InvalidRecordError, NotFoundError,
                     StorageError)

from .schemas import ErrorPublic

log = logging.getLogger("neuenh.api")


def documented(described: dict[int, str]) -> dict[int, dict]:
    """OpenAPI ``responses`` for error statuses, each answered with ``ErrorPublic``."""
    return {code: {"model": ErrorPublic, "description": text} for code, text in described.items()}


# Every /v1 route behind the token can answer these.
COMMON = documented({401: "missing or invalid bearer token",
                     422: "invalid request: each problem named in detail"})
# A stored artifact changed since it was written (HTTP 507 "Insufficient Storage": the storage failed).
DAMAGED_ARTIFACT = status.HTTP_507_INSUFFICIENT_STORAGE
# Routes that read stored artifacts can answer this.
DAMAGED = documented({DAMAGED_ARTIFACT: "a stored artifact is damaged (detail names it): restore it from a backup"})


def _json(code: int, detail, **extra) -> JSONResponse:
    return JSONResponse(status_code=code, content={"detail": detail, **extra})


def _where(loc) -> str:
    parts = [str(p) for p in loc]
    if parts and parts[0] == "body":
        return ".".join(parts[1:]) or "body"
    return ".".join(parts) or "request"


async def _validation(request: Request, exc: RequestValidationError) -> JSONResponse:
    errors = exc.errors()
    problems = "; ".join(f"{_where(e['loc'])}: {e['msg']}" for e in errors)
    submitting = getattr(request.scope.get("route"), "name", None) == "submit_job"
    what = "invalid job spec" if submitting and any(e["loc"][:1] == ("body",) for e in errors) else "invalid request"
    clean = [{k: v for k, v in e.items() if k in ("loc", "msg", "type")} for e in errors]
    return _json(status.HTTP_422_UNPROCESSABLE_CONTENT, f"{what}: {problems}", errors=jsonable_encoder(clean))


async def _spec_error(request: Request, exc: SpecError) -> JSONResponse:
    return _json(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc))


async def _storage(request: Request, exc: StorageError) -> JSONResponse:
    if isinstance(exc, NotFoundError):
        return _json(status.HTTP_404_NOT_FOUND, str(exc))
    if isinstance(exc, ConflictError):
        return _json(status.HTTP_409_CONFLICT, str(exc))
    if isinstance(exc, (InvalidRecordError, InvalidKeyError)):
        return _json(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc))
    if isinstance(exc, CorruptArtifactError):  # named, never served: the operator restores it from a backup
        log.error("%s %s: %s", request.method, request.url.path, exc)
        return _json(DAMAGED_ARTIFACT, f"{exc} (restore it from a backup: docs/DEPLOY.md)")
    return await _unexpected(request, exc)


async def _http(request: Request, exc: StarletteHTTPException) -> JSONResponse:
    """As FastAPI's own, but a 405 lists in ``Allow`` the methods of *every* route at the path:
    Starlette names only those of the first route it matched (GET and POST /v1/jobs are two)."""
    if exc.status_code == status.HTTP_405_METHOD_NOT_ALLOWED:
        allowed = [method for method in ("GET", "HEAD", "POST", "PUT", "PATCH", "DELETE")
                   if any(route.matches({**request.scope, "method": method})[0] == Match.FULL
                          for route in request.app.router.routes)]
        exc.headers = {**(exc.headers or {}), "Allow": ", ".join(allowed)}
    return await http_exception_handler(request, exc)


async def _unexpected(request: Request, exc: Exception) -> JSONResponse:
    log.error("%s %s failed", request.method, request.url.path, exc_info=exc)
    return _json(status.HTTP_500_INTERNAL_SERVER_ERROR, "internal server error; see the service log")


def install(app: FastAPI) -> None:
    app.add_exception_handler(RequestValidationError, _validation)
    app.add_exception_handler(StarletteHTTPException, _http)
    app.add_exception_handler(SpecError, _spec_error)
    app.add_exception_handler(StorageError, _storage)
    app.add_exception_handler(Exception, _unexpected)
