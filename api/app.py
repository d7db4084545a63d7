"""The FastAPI app. ``create_app(settings)`` builds nothing at import time; its lifespan builds

* ``SQLiteJobStore(data_dir/jobs.sqlite)`` and the artifact store (``artifact_store``: the
  ``NEUENH_S3_BUCKET`` bucket when set, else ``LocalArtifactStore(data_dir/artifacts)``),
* the executor (``RayExecutor`` joining ``ray_address`` or an embedded Ray; tests pass
  ``executor_factory`` returning an ``InlineExecutor``),
* the store's ``OwnerLock`` (one process runs a store's jobs at a time; ``serve`` takes it before
  uvicorn starts, so a second server fails with one line instead of a startup traceback),
* the ``JobQueue`` (one thread running jobs one at a time through the ``Orchestrator``; it
  resumes unfinished jobs at start),
* the lock that lets one ``/fit`` (or plan upload) run at a time (others get 429),
* the ``SQLitePlanStore`` (on the same file) and the ``PlanQueue`` (scene plans, one at a time, each
  in a process of its own holding a fair share beside the jobs; it resumes unfinished plans at start),

puts them on ``app.state`` for ``deps.py``, and on shutdown stops the job queue at a safe point (the
running job is not cancelled: it resumes on the next start) and closes the executor and stores.
"""

from __future__ import annotations

import asyncio
import logging
import math
import signal
import threading
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Callable

from fastapi import APIRouter, Depends, FastAPI

import neuenh
from neuenh.scene import SceneError, parse_scene
from neuenh_service.orchestrator.executor import Executor
from neuenh_service.storage import OwnerLock, PlanRecord, SQLiteJobStore, SQLitePlanStore

from . import deps, errors
from .auth import TokenTable
from .middleware import AuthFirst, BodyLimit, HostCheck
from .metrics import ServiceMetrics
from .routes import cluster, dashboard, docs, fit, health, jobs, metrics, plans
from .settings import Settings
from .stores import artifact_store, owner_lock
from .job_queue import JobQueue
from .limits import plan_problems
from .plan_queue import PlanQueue
from .uploads import PLAN_UPLOADS, PlanUploads

log = logging.getLogger("neuenh.api")

ExecutorFactory = Callable[[Settings], Executor]


def ray_executor(settings: Settings) -> Executor:
    from neuenh_service.workers.ray_executor import RayExecutor  # Ray only when the service really starts

    return RayExecutor(address=settings.ray_address, num_cpus=settings.ray_num_cpus)


def create_app(settings: Settings | None = None, *, executor_factory: ExecutorFactory | None = None,
               lock: OwnerLock | None = None) -> FastAPI:
    """The service. ``settings`` default to the environment (``NEUENH_*``), read at startup;
    ``lock``, when given, is the store's owner lock already held by the caller; either way the
    lock is released once the job queue has stopped."""

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        s = settings if settings is not None else Settings()
        s.data_dir.mkdir(parents=True, exist_ok=True)
        artifacts = artifact_store(s)
        owned = lock if lock is not None and lock.held else owner_lock(s).acquire()
        store = SQLiteJobStore(s.data_dir / "jobs.sqlite")
        executor = (executor_factory or ray_executor)(s)
        job_queue = JobQueue(store, artifacts, executor, resource_wait_s=s.resource_wait_s,
                             max_running=s.max_running_jobs or max(2, math.ceil(executor.cluster().cpus / 12)))
        app.state.settings, app.state.jobs, app.state.artifacts = s, store, artifacts
        app.state.tokens = TokenTable(s)  # a bad tokens file fails the start (serve checks it first)
        _reload_tokens_on_sighup(app.state.tokens)
        app.state.job_queue = job_queue
        # Fits share the CPUs with the candidates being trained: two at once would only slow each other.
        app.state.fit_lock = threading.Lock()
        plan_store = SQLitePlanStore(s.data_dir / "jobs.sqlite")
        app.state.plan_uploads = uploads = PlanUploads(s.data_dir / PLAN_UPLOADS, app.state.fit_lock)
        app.state.plans = plan_store
        app.state.plan_queue = PlanQueue(plan_store, s, share=job_queue.share,
                                         admit=lambda plan: _over_limits(plan, s),
                                         on_ended=lambda plan: uploads.release(plan, plan_store))
        app.state.metrics = ServiceMetrics(store, job_queue, executor)
        job_queue.start()
        swept = uploads.sweep(plan_store)
        if swept:
            log.info("removed %d uploaded file(s) no unfinished plan names", len(swept))
        app.state.plan_queue.start()
        log.info("neuenh service: data in %s, artifacts in %r, auth %s", s.data_dir, artifacts,
                 "on" if s.api_token else "off")
        try:
            yield
        finally:
            stopped = job_queue.stop(s.shutdown_grace_s) & app.state.plan_queue.stop(s.shutdown_grace_s)
            if stopped:  # never pull the store or executor from under a job or plan still running
                executor.close()
                store.close()
                plan_store.close()
                artifacts.close()
                owned.release()  # also serve's: uvicorn ends the process by re-raising the signal

    app = FastAPI(
        title="neuenh",
        version=neuenh.__version__,
        summary="Neural enhancement of analytical BRDF models: a distributed search service.",
        lifespan=lifespan,
        docs_url=None,   # served by routes/docs from packaged assets: the CDN default fails offline
        redoc_url=None,
    )
    errors.install(app)
    v1 = APIRouter(prefix="/v1", dependencies=[Depends(deps.known_query_only)])
    for resource in (health, jobs, fit, plans, cluster):
        v1.include_router(resource.router)
    v1.include_router(plans.uploads)
    app.include_router(v1)
    app.include_router(metrics.router)
    app.include_router(dashboard.router)
    app.mount("/dashboard", dashboard.static_files(), name="dashboard")
    app.include_router(docs.router)
    app.mount(docs.ASSETS_URL, docs.static_files(), name="docs-assets")
    app.add_middleware(BodyLimit, limit=lambda path: body_limit(app.state.settings, path))
    app.add_middleware(AuthFirst, tokens=lambda: app.state.tokens)  # before any body is read
    app.add_middleware(HostCheck, settings=lambda: app.state.settings)  # outermost
    return app


def _over_limits(plan: PlanRecord, settings: Settings) -> list[str]:
    """What of a stored plan the service's limits no longer admit (a scene that no longer parses is
    the planner's to fail, naming the field)."""
    try:
        return plan_problems(parse_scene(plan.scene), settings, Path.cwd())
    except SceneError:
        return []


def _reload_tokens_on_sighup(tokens: TokenTable) -> None:
    """SIGHUP re-reads NEUENH_TOKENS_FILE, as a callback of the event loop (never inside a
    request). Only the main thread's loop can handle signals: a server run in a thread (tests)
    has no SIGHUP reload."""
    try:
        asyncio.get_running_loop().add_signal_handler(signal.SIGHUP, tokens.reload)
    except (RuntimeError, ValueError, NotImplementedError):
        pass


def body_limit(settings: Settings, path: str) -> tuple[int, str]:
    """The largest body a request to ``path`` may send, and the setting that says so."""
    if (path.startswith("/v1/jobs/") and path.endswith("/fit")) or path == "/v1/plan-uploads":
        return settings.max_upload_bytes, "NEUENH_MAX_UPLOAD_BYTES"
    return settings.max_request_bytes, "NEUENH_MAX_REQUEST_BYTES"
