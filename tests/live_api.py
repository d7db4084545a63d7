"""A real uvicorn server on 127.0.0.1 (free port, in a thread) serving ``create_app(settings)``
with real SQLite under tmp_path and the in-process executor, plus an httpx client for it."""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from typing import Iterator

import httpx
import pytest
import uvicorn

from neuenh_service.api.app import create_app
from neuenh_service.api.server import uvicorn_config
from neuenh_service.api.settings import Settings
from neuenh_service.workers.inline import InlineExecutor

TERMINAL = {"CONVERGED", "STOPPED", "CANCELLED", "FAILED"}


class LiveServer:
    def __init__(self, settings: Settings, setup=None):
        self.settings = settings
        self.app = create_app(settings, executor_factory=lambda s: InlineExecutor())
        if setup is not None:
            setup(self.app)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM, socket.IPPROTO_TCP)
        self.sock.bind(("127.0.0.1", 0))
        self.url = f"http://127.0.0.1:{self.sock.getsockname()[1]}"
        # the service's own uvicorn configuration (connection limit, request-head deadline)
        self.server = uvicorn.Server(uvicorn_config(self.app, settings, log_level="warning"))
        self.thread = threading.Thread(target=self.server.run, kwargs={"sockets": [self.sock]}, daemon=True)

    def start(self) -> "LiveServer":
        self.thread.start()
        deadline = time.monotonic() + 20
        while not self.server.started:
            if not self.thread.is_alive() or time.monotonic() > deadline:
                raise RuntimeError("the test server did not start")
            time.sleep(0.02)
        return self

    def stop(self) -> None:
        self.server.should_exit = True
        self.thread.join(60)
        self.sock.close()
        assert not self.thread.is_alive(), "the test server did not stop"

    def client(self, **kw) -> httpx.Client:
        return httpx.Client(base_url=self.url + "/v1", timeout=30, **kw)


@contextlib.contextmanager
def running_server(data_dir, setup=None, **settings) -> Iterator[LiveServer]:
    """A live server on ``data_dir`` with ``settings`` for the ``with`` block (module fixtures)."""
    server = LiveServer(Settings(data_dir=data_dir, **settings), setup).start()
    try:
        yield server
    finally:
        server.stop()


@pytest.fixture()
def live_server(tmp_path):
    """Factory: ``live_server(**settings)`` starts a server; every one is stopped at the end."""
    servers: list[LiveServer] = []

    def start(setup=None, **overrides) -> LiveServer:
        settings = Settings(**{"data_dir": tmp_path / "data", **overrides})
        servers.append(LiveServer(settings, setup).start())
        return servers[-1]

    yield start
    for s in servers:
        if s.thread.is_alive():
            s.stop()


def wait_plan(client: httpx.Client, plan_id: str, timeout: float = 180.0) -> dict:
    """The plan once it has ended (DONE or FAILED)."""
    deadline = time.monotonic() + timeout
    while True:
        plan = client.get(f"/plans/{plan_id}").json()
        if plan["terminal"]:
            return plan
        assert time.monotonic() < deadline, plan
        time.sleep(0.2)


def wait_for(client: httpx.Client, job_id: str, until=lambda job: job["terminal"],
             timeout: float = 60.0, kind: str = "jobs") -> dict:
    """The job (or with ``kind="plans"`` the plan) once ``until`` holds: by default, once it ended."""
    deadline = time.monotonic() + timeout
    while True:
        r = client.get(f"/{kind}/{job_id}")
        assert r.status_code == 200, r.text
        job = r.json()
        if until(job):
            return job
        if time.monotonic() > deadline:
            raise AssertionError(f"{kind[:-1]} {job_id} stuck at {job['status']}")
        time.sleep(0.1)
