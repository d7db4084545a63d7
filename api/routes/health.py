"""``GET /v1/health``: open (no token), for load balancers and ``neuenh-client``'s reachability check."""

from __future__ import annotations

from fastapi import APIRouter

import neuenh

from ..deps import SettingsDep, WorkerDep
from ..schemas import Health

router = APIRouter(tags=["health"])


@router.get("/health", response_model=Health)
def health(settings: SettingsDep, worker: WorkerDep) -> Health:
    return Health(status="ok" if worker.alive else "degraded", version=neuenh.__version__,
                  worker_alive=worker.alive, auth=settings.api_token is not None)
