"""``neuenh serve`` as a real subprocess (real uvicorn, real embedded Ray, real SQLite) on a free
loopback port, for tests that need the whole service: start, crash, restart, clean shutdown."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import httpx

NEUENH = str(Path(sys.executable).parent / "neuenh")
REPO = Path(__file__).resolve().parents[1]


def clean_env(**extra: str) -> dict[str, str]:
    """This environment without NEUENH_* or RAY_ADDRESS (a developer's settings must not leak in)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("NEUENH_") and k != "RAY_ADDRESS"}
    return {**env, **extra}


def follow(proc: subprocess.Popen, pattern: str, timeout: float = 60) -> tuple[list[str], str | None]:
    """Read ``proc``'s output in a thread for as long as it runs (so it never blocks on a full
    pipe) into the returned list of lines; wait until a line matches ``pattern`` (or the output
    ends) and return its first group, e.g. the address a server announces."""
    lines: list[str] = []
    found: list[str] = []
    announced = threading.Event()

    def pump() -> None:
        for line in proc.stdout:
            lines.append(line.rstrip("\n"))
            match = re.search(pattern, line)
            if match and not found:
                found.append(match.group(1))
                announced.set()
        announced.set()

    threading.Thread(target=pump, daemon=True).start()
    announced.wait(timeout)
    return lines, (found[0] if found else None)


class ServeProcess:
    def __init__(self, data_dir: Path, *args: str, env: dict[str, str] | None = None):
        self.data_dir = data_dir
        self.proc = subprocess.Popen(
            [NEUENH, "serve", "--port", "0", "--cpus", "2", "--data-dir", str(data_dir), *args],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=REPO,
            env=clean_env(**(env or {})))
        self.lines, self.url = follow(self.proc, r"dashboard (http://\S+?)/ ")

    @property
    def output(self) -> str:
        return "\n".join(self.lines)

    def wait_ready(self, timeout: float = 120.0) -> "ServeProcess":
        """Until ``/v1/health`` answers (the lifespan has started Ray and the worker)."""
        assert self.url, f"neuenh serve did not announce its address:\n{self.output}"
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            assert self.proc.poll() is None, f"neuenh serve exited {self.proc.returncode}:\n{self.output}"
            try:
                if httpx.get(self.url + "/v1/health", timeout=5).status_code == 200:
                    return self
            except httpx.HTTPError:
                pass
            time.sleep(0.25)
        raise AssertionError(f"neuenh serve not ready after {timeout} s:\n{self.output}")

    def client(self, **kw) -> httpx.Client:
        return httpx.Client(base_url=self.url + "/v1", timeout=30, **kw)

    def children(self) -> set[int]:
        """Live descendants of the server process (Ray's GCS, raylet, workers...)."""
        parents: dict[int, int] = {}
        for stat in Path("/proc").glob("[0-9]*/stat"):
            try:
                fields = stat.read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            parents[int(stat.parent.name)] = int(fields[1])
        found, frontier = set(), {self.proc.pid}
        while frontier:
            frontier = {pid for pid, ppid in parents.items() if ppid in frontier} - found
            found |= frontier
        return found

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 60.0) -> int:
        """Send ``sig`` and wait. After SIGKILL (a crash) the descendants are killed too, as a
        container runtime would: Ray's agents outlive a killed driver (``ray stop`` cleans them
        outside a container)."""
        orphans = self.children() if sig == signal.SIGKILL else set()
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        for pid in orphans:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        try:
            return self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            raise AssertionError(f"neuenh serve did not stop within {timeout} s:\n{self.output}")
