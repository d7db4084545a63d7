"""``GET /v1/cluster``: the nodes candidates train on, their CPUs and GPUs, and what is busy."""

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
    return ClusterPublic.model_validate({**dataclasses.asdict(info), "running_job": job_queue.current})
