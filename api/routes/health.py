"""``GET /v1/health``: open (no token), for load balancers and ``neuenh-client``'s reachability check."""

from __future__ import annotations

from fastapi import APIRouter

import neuenh

from ..deps import SettingsDep, JobQueueDep
from ..schemas import Health

router = APIRouter(tags=["health"])


@router.get("/health", response_model=Health)
async def health(settings: SettingsDep, job_queue: JobQueueDep) -> Health:
    """On the event loop, never in the worker-thread pool: it answers however busy the routes that
    run there are."""
    ok = job_queue.alive and not job_queue.broken
    return Health(status="ok" if ok else "degraded", version=neuenh.__version__, worker_alive=job_queue.alive,
                  auth=settings.has_tokens, broken_jobs=dict(job_queue.broken))
