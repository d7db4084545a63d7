"""``GET /v1/cluster``: the nodes candidates train on, their CPUs and GPUs, what is busy, and which
running job holds which share of it."""

from __future__ import annotations

import dataclasses

from fastapi import APIRouter

from ..deps import Authorized, JobQueueDep
from ..errors import COMMON
from ..schemas import ClusterPublic

router = APIRouter(tags=["cluster"], dependencies=[Authorized], responses=COMMON)


@router.get("/cluster", response_model=ClusterPublic)
def cluster(job_queue: JobQueueDep) -> ClusterPublic:
    info = job_queue.orchestrator.executor.cluster()
    return ClusterPublic.model_validate({**dataclasses.asdict(info), "running_jobs": job_queue.running,
                                         "max_running_jobs": job_queue.max_running})
