"""``GET /v1/cluster``: the nodes candidates train on, their CPUs and GPUs, what is busy, and which
running job holds which share of it. A submit token sees its own jobs' ids; another owner's running
jobs count in the figures but are not named (as everywhere, another owner's job is as if absent)."""

from __future__ import annotations

import dataclasses

from fastapi import APIRouter

from neuenh_service.storage import NotFoundError

from ..deps import Authorized, JobQueueDep, JobStoreDep, PrincipalDep
from ..errors import COMMON
from ..schemas import ClusterPublic

router = APIRouter(tags=["cluster"], dependencies=[Authorized], responses=COMMON)


@router.get("/cluster", response_model=ClusterPublic)
def cluster(job_queue: JobQueueDep, jobs: JobStoreDep, principal: PrincipalDep) -> ClusterPublic:
    info = dataclasses.asdict(job_queue.orchestrator.executor.cluster())
    running = job_queue.running
    if not principal.sees_all:
        named = {*running, *(h["job_id"] for h in info["holders"])}
        own = {job_id for job_id in named if _owned(jobs, job_id, principal)}
        running = [job_id for job_id in running if job_id in own]
        info["holders"] = [{**h, "job_id": h["job_id"] if h["job_id"] in own else None} for h in info["holders"]]
    return ClusterPublic.model_validate({**info, "running_jobs": running,
                                         "other_running_jobs": len(job_queue.running) - len(running),
                                         "max_running_jobs": job_queue.max_running})


def _owned(jobs, job_id: str, principal) -> bool:
    try:
        return principal.may_see(jobs.get_job(job_id).owner)
    except NotFoundError:
        return False
