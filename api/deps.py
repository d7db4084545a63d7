"""Dependencies of the routes, as ``Annotated`` aliases. Everything comes from
``request.app.state``, which the app's lifespan fills; tests build their own app with
``create_app(settings, executor_factory=...)`` instead of patching globals. The getters are
``async``: reading ``app.state`` never blocks, so they take no thread of AnyIO's pool (which a
route like ``/v1/health`` then never waits for)."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Annotated

from fastapi import Depends, HTTPException, Request, status
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from neuenh_service.storage import ArtifactStore, JobRecord, JobStore, NotFoundError, PlanRecord, PlanStore

from .auth import Principal, Role
from .settings import Settings
from .job_queue import JobQueue
from .plan_queue import PlanQueue


async def get_settings(request: Request) -> Settings:
    return request.app.state.settings


async def get_jobs(request: Request) -> JobStore:
    return request.app.state.jobs


async def get_artifacts(request: Request) -> ArtifactStore:
    return request.app.state.artifacts


async def get_job_queue(request: Request) -> JobQueue:
    return request.app.state.job_queue


async def get_plans(request: Request) -> PlanStore:
    return request.app.state.plans


async def get_plan_queue(request: Request) -> PlanQueue:
    return request.app.state.plan_queue


async def get_fit_lock(request: Request) -> threading.Lock:
    return request.app.state.fit_lock


# A fit or an upload that finds another one running waits this long, then gets 429 with Retry-After.
FIT_WAIT_S = 0.5
FIT_RETRY_AFTER_S = 10


@contextmanager
def fit_slot(lock: threading.Lock) -> Iterator[None]:
    """Hold the service's one fit slot (fits and plan uploads, one at a time: each costs memory like
    a fit), or answer 429 with ``Retry-After`` when another request still holds it after a short wait.
    A request waiting longer would hold one of AnyIO's 40 worker threads, and enough such waiters
    left none for any other route (``/v1/health`` timed out)."""
    if not lock.acquire(timeout=FIT_WAIT_S):
        raise HTTPException(status.HTTP_429_TOO_MANY_REQUESTS,
                            "another fit or measurement upload is running on this service (one at a time); "
                            f"retry in {FIT_RETRY_AFTER_S} s", headers={"Retry-After": str(FIT_RETRY_AFTER_S)})
    try:
        yield
    finally:
        lock.release()


SettingsDep = Annotated[Settings, Depends(get_settings)]
JobStoreDep = Annotated[JobStore, Depends(get_jobs)]
ArtifactStoreDep = Annotated[ArtifactStore, Depends(get_artifacts)]
JobQueueDep = Annotated[JobQueue, Depends(get_job_queue)]
FitLockDep = Annotated[threading.Lock, Depends(get_fit_lock)]
PlanStoreDep = Annotated[PlanStore, Depends(get_plans)]
PlanQueueDep = Annotated[PlanQueue, Depends(get_plan_queue)]

_bearer = HTTPBearer(auto_error=False, description="a named token (NEUENH_TOKENS_FILE) or NEUENH_API_TOKEN")


def current_principal(request: Request,
                      _: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)]) -> Principal:
    """The caller (``api.auth``): 401 without a valid token when the service has tokens. (The
    ``HTTPBearer`` parameter only documents the scheme in the OpenAPI schema.)"""
    return request.app.state.tokens.authenticate(request.headers.get("authorization"))


Authorized = Depends(current_principal)
PrincipalDep = Annotated[Principal, Depends(current_principal)]


def submitter(principal: PrincipalDep) -> Principal:
    """A caller who may submit jobs and fit with them: not the read role (403)."""
    if principal.role is Role.READ:
        raise HTTPException(status.HTTP_403_FORBIDDEN, f"token {principal.name!r} has the read role: it can look, "
                                                       "not submit, cancel or fit")
    return principal


SubmitterDep = Annotated[Principal, Depends(submitter)]


def visible_job(job_id: str, jobs: JobStoreDep, principal: PrincipalDep) -> JobRecord:
    """The job, if the caller may see it; another submitter's job is 404, as if it did not exist."""
    job = jobs.get_job(job_id)
    if not principal.may_see(job.owner):
        raise NotFoundError(f"no job {job_id!r}")
    return job


VisibleJob = Annotated[JobRecord, Depends(visible_job)]


def changeable_job(job: VisibleJob, principal: SubmitterDep) -> JobRecord:
    """The job, if the caller may change it (cancel it, fit with it): its owner or an admin."""
    if not principal.may_change(job.owner):
        raise HTTPException(status.HTTP_403_FORBIDDEN, f"token {principal.name!r} cannot change job {job.id}")
    return job


ChangeableJob = Annotated[JobRecord, Depends(changeable_job)]


async def known_query_only(request: Request) -> None:
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


def visible_plan(plan_id: str, plans: PlanStoreDep, principal: PrincipalDep) -> PlanRecord:
    """The plan, if the caller may see it (as ``visible_job``)."""
    plan = plans.get_plan(plan_id)
    if not principal.may_see(plan.owner):
        raise NotFoundError(f"no plan {plan_id!r}")
    return plan


VisiblePlan = Annotated[PlanRecord, Depends(visible_plan)]


def changeable_plan(plan: VisiblePlan, principal: SubmitterDep) -> PlanRecord:
    """The plan, if the caller may change it (cancel it): its owner or an admin."""
    if not principal.may_change(plan.owner):
        raise HTTPException(status.HTTP_403_FORBIDDEN, f"token {principal.name!r} cannot change plan {plan.id}")
    return plan


ChangeablePlan = Annotated[PlanRecord, Depends(changeable_plan)]
