"""Dependencies of the routes, as ``Annotated`` aliases. Everything comes from
``request.app.state``, which the app's lifespan fills; tests build their own app with
``create_app(settings, executor_factory=...)`` instead of patching globals."""

from __future__ import annotations

import hmac
from typing import Annotated

from fastapi import Depends, HTTPException, Request, status
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from storage import ArtifactStore, JobStore

from .settings import Settings
from .worker import JobWorker


def get_settings(request: Request) -> Settings:
    return request.app.state.settings


def get_jobs(request: Request) -> JobStore:
    return request.app.state.jobs


def get_artifacts(request: Request) -> ArtifactStore:
    return request.app.state.artifacts


def get_worker(request: Request) -> JobWorker:
    return request.app.state.worker


SettingsDep = Annotated[Settings, Depends(get_settings)]
JobStoreDep = Annotated[JobStore, Depends(get_jobs)]
ArtifactStoreDep = Annotated[ArtifactStore, Depends(get_artifacts)]
WorkerDep = Annotated[JobWorker, Depends(get_worker)]

_bearer = HTTPBearer(auto_error=False, description="the service's NEUENH_API_TOKEN")


def require_token(settings: SettingsDep,
                  credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)]) -> None:
    """With ``api_token`` set, demand ``Authorization: Bearer <token>`` (constant-time compare)."""
    if settings.api_token is None:
        return
    if credentials is None:
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, "missing bearer token (Authorization: Bearer <token>)",
                            headers={"WWW-Authenticate": "Bearer"})
    expected = settings.api_token.get_secret_value().encode()
    if not hmac.compare_digest(credentials.credentials.encode(), expected):
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, "invalid bearer token",
                            headers={"WWW-Authenticate": 'Bearer error="invalid_token"'})


Authorized = Depends(require_token)
