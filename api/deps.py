"""Dependencies of the routes, as ``Annotated`` aliases. Everything comes from
``request.app.state``, which the app's lifespan fills; tests build their own app with
``create_app(settings, executor_factory=...)`` instead of patching globals."""

from __future__ import annotations

import hmac
import threading
from typing import Annotated

from fastapi import Depends, HTTPException, Request, status
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from storage import ArtifactStore, JobStore

from .settings import Settings
from .job_queue import JobQueue


def get_settings(request: Request) -> Settings:
    return request.app.state.settings


def get_jobs(request: Request) -> JobStore:
    return request.app.state.jobs


def get_artifacts(request: Request) -> ArtifactStore:
    return request.app.state.artifacts


def get_job_queue(request: Request) -> JobQueue:
    return request.app.state.job_queue


def get_fit_lock(request: Request) -> threading.Lock:
    return request.app.state.fit_lock


SettingsDep = Annotated[Settings, Depends(get_settings)]
JobStoreDep = Annotated[JobStore, Depends(get_jobs)]
ArtifactStoreDep = Annotated[ArtifactStore, Depends(get_artifacts)]
JobQueueDep = Annotated[JobQueue, Depends(get_job_queue)]
FitLockDep = Annotated[threading.Lock, Depends(get_fit_lock)]

_bearer = HTTPBearer(auto_error=False, description="the service's NEUENH_API_TOKEN")


def token_refusal(settings: Settings, authorization: str | None) -> HTTPException | None:
    """The 401 for an ``Authorization`` header value, or None when it may pass: with ``api_token``
    set, ``Bearer <token>`` is demanded (constant-time compare). Shared by the route dependency and
    the middleware that refuses before a body is read (``api.app.AuthFirst``)."""
    if settings.api_token is None:
        return None
    scheme, _, token = (authorization or "").partition(" ")
    if scheme.lower() != "bearer" or not token.strip():
        return HTTPException(status.HTTP_401_UNAUTHORIZED, "missing bearer token (Authorization: Bearer <token>)",
                             headers={"WWW-Authenticate": "Bearer"})
    expected = settings.api_token.get_secret_value().encode()
    if not hmac.compare_digest(token.strip().encode(), expected):
        return HTTPException(status.HTTP_401_UNAUTHORIZED, "invalid bearer token",
                             headers={"WWW-Authenticate": 'Bearer error="invalid_token"'})
    return None


def require_token(settings: SettingsDep,
                  credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)]) -> None:
    """With ``api_token`` set, demand ``Authorization: Bearer <token>`` (see ``token_refusal``)."""
    header = None if credentials is None else f"{credentials.scheme} {credentials.credentials}"
    refusal = token_refusal(settings, header)
    if refusal is not None:
        raise refusal


Authorized = Depends(require_token)


def known_query_only(request: Request) -> None:
    """Refuse query parameters the route does not declare (422 naming them), so a typo such as
    ``?since=3`` for ``?since_round=3`` is an error rather than silently the whole history."""
    route = request.scope.get("route")
    if route is None or not hasattr(route, "dependant") or not request.query_params:
        return
    known, pending = set(), [route.dependant]
    while pending:  # the route's own parameters and those of its dependencies
        dependant = pending.pop()
        known |= {param.alias for param in dependant.query_params}
        pending += dependant.dependencies
    unknown = sorted(set(request.query_params) - known)
    if unknown:
        expected = ", ".join(sorted(known)) or "none"
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"unknown query parameter(s) {', '.join(unknown)}; this route takes: {expected}")
