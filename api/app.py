"""The FastAPI app. ``create_app(settings)`` builds nothing at import time; its lifespan builds

* ``SQLiteJobStore(data_dir/jobs.sqlite)`` and the artifact store (``artifact_store``: the
  ``NEUENH_S3_BUCKET`` bucket when set, else ``LocalArtifactStore(data_dir/artifacts)``),
* the executor (``RayExecutor`` joining ``ray_address`` or an embedded Ray; tests pass
  ``executor_factory`` returning an ``InlineExecutor``),
* the store's ``OwnerLock`` (one process runs a store's jobs at a time; ``serve`` takes it before
  uvicorn starts, so a second server fails with one line instead of a startup traceback),
* the ``JobQueue`` (one thread running jobs one at a time through the ``Orchestrator``; it
  resumes unfinished jobs at start),
* the lock that lets one ``/fit`` run at a time,

puts them on ``app.state`` for ``deps.py``, and on shutdown stops the job queue at a safe point (the
running job is not cancelled: it resumes on the next start) and closes the executor and stores.
"""

from __future__ import annotations

import ipaddress
import logging
import threading
from contextlib import asynccontextmanager
from typing import Callable

from fastapi import APIRouter, Depends, FastAPI, HTTPException, status
from fastapi.responses import JSONResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send

import neuenh
from orchestrator.executor import Executor
from storage import ArtifactStore, LocalArtifactStore, OwnerLock, SQLiteJobStore

from . import deps, errors
from .routes import cluster, dashboard, docs, fit, health, jobs
from .settings import Settings
from .job_queue import JobQueue

log = logging.getLogger("neuenh.api")

ExecutorFactory = Callable[[Settings], Executor]


def ray_executor(settings: Settings) -> Executor:
    from workers.ray_executor import RayExecutor  # Ray only when the service really starts

    return RayExecutor(address=settings.ray_address, num_cpus=settings.ray_num_cpus)


def artifact_store(settings: Settings) -> ArtifactStore:
    """The bucket when ``s3_bucket`` is set (checked: a ``StorageError`` naming a missing bucket or
    an unreachable endpoint), else the directory ``data_dir/artifacts``."""
    if not settings.s3_bucket:
        return LocalArtifactStore(settings.data_dir / "artifacts")
    from storage.s3 import S3ArtifactStore  # boto3 only for a bucket

    secret = settings.s3_secret_access_key
    return S3ArtifactStore(settings.s3_bucket, prefix=settings.s3_prefix,
                           endpoint_url=settings.s3_endpoint_url, region=settings.s3_region,
                           access_key_id=settings.s3_access_key_id,
                           secret_access_key=secret.get_secret_value() if secret else None,
                           max_attempts=settings.s3_max_attempts)


def owner_lock(settings: Settings) -> OwnerLock:
    return OwnerLock(settings.data_dir / "owner.lock", owner="neuenh serve")


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
        job_queue = JobQueue(store, artifacts, executor)
        app.state.settings, app.state.jobs, app.state.artifacts = s, store, artifacts
        app.state.job_queue = job_queue
        # Fits share the CPUs with the candidates being trained: two at once would only slow each other.
        app.state.fit_lock = threading.Lock()
        job_queue.start()
        log.info("neuenh service: data in %s, artifacts in %r, auth %s", s.data_dir, artifacts,
                 "on" if s.api_token else "off")
        try:
            yield
        finally:
            stopped = job_queue.stop(s.shutdown_grace_s)
            if stopped:  # never pull the store or executor from under a job still running
                executor.close()
                store.close()
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
    for resource in (health, jobs, fit, cluster):
        v1.include_router(resource.router)
    app.include_router(v1)
    app.include_router(dashboard.router)
    app.mount("/dashboard", dashboard.static_files(), name="dashboard")
    app.include_router(docs.router)
    app.mount(docs.ASSETS_URL, docs.static_files(), name="docs-assets")
    app.add_middleware(BodyLimit, limit=lambda path: body_limit(app.state.settings, path))
    app.add_middleware(AuthFirst, settings=lambda: app.state.settings)  # before any body is read
    app.add_middleware(HostCheck, settings=lambda: app.state.settings)  # outermost
    return app


class HostCheck:
    """Answer only requests whose ``Host`` is one of this service's names (421 otherwise): a web
    page can make a browser's requests to ``attacker.example`` land on 127.0.0.1 by DNS rebinding,
    and a token-less loopback service would obey them. ``NEUENH_ALLOWED_HOSTS`` lists the names;
    unset, a token-less service answers loopback names only and a token-protected one any."""

    def __init__(self, app: ASGIApp, settings: Callable[[], Settings]):
        self.app, self.settings = app, settings

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http":
            host = _host_name(dict(scope["headers"]).get(b"host", b"").decode("latin-1"))
            settings = self.settings()
            allowed = [h.lower() for h in settings.allowed_hosts]
            if allowed:
                ok = host in allowed
            else:
                ok = settings.api_token is not None or host in ("localhost", settings.host.lower()) \
                    or _is_ip_loopback(host)
            if not ok:
                detail = f"this service does not answer to Host {host!r} (NEUENH_ALLOWED_HOSTS)"
                await JSONResponse({"detail": detail}, status.HTTP_421_MISDIRECTED_REQUEST)(scope, receive, send)
                return
        await self.app(scope, receive, send)


def _host_name(header: str) -> str:
    """The name of a Host header value, lowercased, without the port (``[::1]:8000`` -> ``::1``)."""
    header = header.strip().lower()
    if header.startswith("["):
        return header[1:].partition("]")[0]
    return header.rpartition(":")[0] if header.count(":") == 1 else header


def _is_ip_loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class AuthFirst:
    """Refuse a request to a token-protected ``/v1`` route with 401 *before* its body is read:
    FastAPI parses a JSON body, and spools a multipart upload to disk, before it runs the routes'
    dependencies, so without this a client with no token could make the service store 64 MB, or
    learn from a 422 what a valid body looks like."""

    OPEN = ("/v1/health",)

    def __init__(self, app: ASGIApp, settings: Callable[[], Settings]):
        self.app, self.settings = app, settings

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        path = scope.get("path", "")
        if scope["type"] == "http" and path.startswith("/v1/") and path not in self.OPEN:
            authorization = dict(scope["headers"]).get(b"authorization")
            refusal = deps.token_refusal(self.settings(), None if authorization is None
                                         else authorization.decode("latin-1"))
            if refusal is not None:
                response = JSONResponse({"detail": refusal.detail}, refusal.status_code, headers=refusal.headers)
                await response(scope, receive, send)
                return
        await self.app(scope, receive, send)


def body_limit(settings: Settings, path: str) -> tuple[int, str]:
    """The largest body a request to ``path`` may send, and the setting that says so."""
    if path.startswith("/v1/jobs/") and path.endswith("/fit"):
        return settings.max_upload_bytes, "NEUENH_MAX_UPLOAD_BYTES"
    return settings.max_request_bytes, "NEUENH_MAX_REQUEST_BYTES"


class BodyLimit:
    """Refuse request bodies over ``limit(path)`` bytes with 413: at once when ``Content-Length`` says
    so, else while the body streams in."""

    def __init__(self, app: ASGIApp, limit: Callable[[str], tuple[int, str]]):
        self.app, self.limit = app, limit

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        limit, setting = self.limit(scope["path"])
        detail = f"request body over {limit} bytes ({setting})"
        length = dict(scope["headers"]).get(b"content-length")
        if length is not None and (not length.isdigit() or int(length) > limit):
            await JSONResponse({"detail": detail}, status.HTTP_413_CONTENT_TOO_LARGE)(scope, receive, send)
            return
        seen = 0

        async def counted() -> Message:
            nonlocal seen
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > limit:  # FastAPI re-raises HTTPException from body reading as-is
                    raise HTTPException(status.HTTP_413_CONTENT_TOO_LARGE, detail)
            return message

        await self.app(scope, counted, send)
