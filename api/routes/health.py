"""``GET /v1/health``: open (no token), for load balancers and ``neuenh-client``'s reachability check."""

from __future__ import annotations

from fastapi import APIRouter

import neuenh

from ..deps import SettingsDep, JobQueueDep
from ..schemas import Health

router = APIRouter(tags=["health"])


@router.get("/health", response_model=Health)
def health(settings: SettingsDep, job_queue: JobQueueDep) -> Health:
    return Health(status="ok" if job_queue.alive else "degraded", version=neuenh.__version__,
                  worker_alive=job_queue.alive, auth=settings.api_token is not None)
