"""``GET /v1/cluster``: the nodes candidates train on, their CPUs and GPUs, and what is busy."""

from __future__ import annotations

import dataclasses

from fastapi import APIRouter

from ..deps import Authorized, WorkerDep
from ..errors import COMMON
from ..schemas import ClusterPublic

router = APIRouter(tags=["cluster"], dependencies=[Authorized], responses=COMMON)


@router.get("/cluster", response_model=ClusterPublic)
def cluster(worker: WorkerDep) -> ClusterPublic:
    info = worker.orchestrator.executor.cluster()
    return ClusterPublic.model_validate({**dataclasses.asdict(info), "running_job": worker.current})
