"""Run the service: ``serve(settings)`` checks what a user can get wrong before anything starts
(a network address without a token, an artifact bucket that is missing or unreachable, a store
owned by another process, a port in use), each as a
one-line ``ValueError``/``StorageError``, then runs uvicorn until SIGINT/SIGTERM and shuts down
cleanly (the running job stops at a safe point and resumes on the next start; Ray is shut down)."""

from __future__ import annotations

import logging
import socket
from typing import Callable

from neuenh.allocator import keep_freed_memory
from neuenh_service.storage import SQLiteJobStore

from .settings import Settings, check_listen_address


def _print_now(line: str) -> None:
    print(line, flush=True)  # at once, also into a file (neuenh serve > serve.log): it tells the URL


def serve(settings: Settings, announce: Callable[[str], None] = _print_now) -> None:
    import uvicorn

    from .auth import TokenTable
    from .stores import artifact_store, owner_lock

    # every check before the app is imported: a mistake is one line in a fraction of a second, not
    # after importing torch (~2-3 s of CPU)
    check_listen_address(settings)
    keep_freed_memory()  # the service's own fits (/fit) reuse their freed activations (neuenh.allocator)
    TokenTable(settings)  # a bad tokens file is one line now, not a startup traceback
    if settings.data_dir.exists() and not settings.data_dir.is_dir():
        raise ValueError(f"data directory {settings.data_dir} (--data-dir, NEUENH_DATA_DIR) exists and is not a folder")
    artifact_store(settings).close()  # a wrong bucket or endpoint is one line now, not a startup traceback
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    lock = owner_lock(settings).acquire()
    try:
        # a damaged or unreadable job database is one line (exit 2) now, not uvicorn's startup traceback
        with SQLiteJobStore(settings.data_dir / "jobs.sqlite") as store:
            store.check_integrity()
        sock = _listen(settings.host, settings.port)
        configure_logging(settings.log_format)
        host, port = sock.getsockname()[:2]
        url = f"http://{'[' + host + ']' if ':' in host else host}:{port}"
        announce(f"neuenh serve: dashboard {url}/  API {url}/v1  docs {url}/docs  data {settings.data_dir}")
        from .app import create_app

        uvicorn.Server(uvicorn_config(create_app(settings, lock=lock), settings)).run(sockets=[sock])
    finally:
        lock.release()


def configure_logging(log_format: str) -> None:
    """The service's log lines on stderr: text, or with "json" one JSON object per line
    (python-json-logger), uvicorn's own loggers included (they then propagate to the root)."""
    handler = logging.StreamHandler()
    if log_format == "json":
        from pythonjsonlogger.json import JsonFormatter

        handler.setFormatter(JsonFormatter("%(asctime)s %(levelname)s %(name)s %(message)s",
                                           rename_fields={"asctime": "time", "levelname": "level", "name": "logger"}))
    else:
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    logging.basicConfig(level=logging.INFO, handlers=[handler])


def uvicorn_config(app, settings: Settings, log_level: str = "info"):
    """The uvicorn configuration the service runs with (and its tests): requests beyond
    ``max_connections`` open connections get 503, and a connection that sends no complete request
    head within ``head_timeout`` s is closed (``api.connections``), so idle clients cannot hold
    the slots."""
    import uvicorn

    from .connections import protocol

    return uvicorn.Config(app, http=protocol(settings.head_timeout), limit_concurrency=settings.max_connections,
                          timeout_graceful_shutdown=10, log_level=log_level,
                          # pollers keep connections open: closing idle ones after uvicorn's
                          # 5 s races with a client reusing them (a reset seen under load)
                          timeout_keep_alive=75, access_log=settings.access_log,
                          # JSON: uvicorn's loggers keep no handlers of their own and reach the root's
                          log_config=None if settings.log_format == "json" else uvicorn.config.LOGGING_CONFIG)


def _listen(host: str, port: int) -> socket.socket:
    """Bind before the app starts, so a busy port is a one-line error and port 0 picks a free one."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    # IPPROTO_TCP spelled out: asyncio sets TCP_NODELAY on accepted connections only when the
    # listening socket says TCP, and without it Nagle plus delayed ACKs add ~40 ms to every answer.
    sock = socket.socket(family, socket.SOCK_STREAM, socket.IPPROTO_TCP)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        raise ValueError(f"cannot listen on {host}:{port}: {exc.strerror or exc}") from None
    sock.set_inheritable(True)
    return sock
