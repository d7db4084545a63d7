"""docker-compose.yml without Docker: each service's command and environment, as compose would
resolve them, run as a local process. What changes on the way, and why (each container has its
own network namespace, /tmp and volumes; local processes share one machine):

* service host names become 127.0.0.1 and container ports free loopback ports
  (``ray-head:6379`` -> ``127.0.0.1:<free>``, ``--port 8000`` -> ``--port <free>``, ``0.0.0.0`` ->
  ``127.0.0.1``);
* ``ray start`` also gets random ports for what Ray would otherwise bind at the same fixed port on
  every node (the dashboard agent, the worker port range). Ray itself cannot be held to loopback:
  it advertises the machine's address and its GCS and raylets listen on every interface, so the
  cluster runs with token authentication (``RAY_AUTH_MODE=token``, as in the compose file);
* every process gets its own ``RAY_TMPDIR`` (a container's /tmp), volumes become directories;
* the object store's image (MinIO) is not available: its command alone is replaced by
  ``moto_server`` on a loopback port (a real S3 server), see ``replace``.

Every process starts in its own session; ``close()`` kills every process of the run, found by its
process tree and by the run's directory in its environment (``ray start`` daemonises its node when
not blocking), so nothing outlives a failed test.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

BIN = Path(sys.executable).parent
# Ray would bind these at the same fixed ports on every node of one machine.
RAY_LOCAL = ["--dashboard-agent-listen-port=0", "--min-worker-port=0", "--max-worker-port=0"]
_VAR = re.compile(r"\$\$|\$\{([A-Za-z_][A-Za-z0-9_]*)(?:(:?[-?])([^}]*))?\}|\$([A-Za-z_][A-Za-z0-9_]*)")


class InterpolationError(ValueError):
    pass


def interpolate(value, env: dict[str, str]):
    """Compose's variable substitution: ``${V}``, ``${V:-default}``, ``${V-default}``,
    ``${V:?error}``, ``${V?error}``, ``$V``; ``$$`` is a literal ``$``."""
    if isinstance(value, dict):
        return {k: interpolate(v, env) for k, v in value.items()}
    if isinstance(value, list):
        return [interpolate(v, env) for v in value]
    if not isinstance(value, str):
        return value

    def one(m: re.Match) -> str:
        if m.group(0) == "$$":
            return "$"
        name, op, arg = m.group(1) or m.group(4), m.group(2), m.group(3)
        current = env.get(name)
        unset = current is None or (op is not None and op.startswith(":") and current == "")
        if op and op.endswith("-"):
            return arg if unset else current
        if op and op.endswith("?"):
            if unset:
                raise InterpolationError(f"{name}: {arg}")
            return current
        return current or ""

    return _VAR.sub(one, value)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def process_tree(root: int) -> set[int]:
    """``root`` and its live descendants."""
    parents: dict[int, int] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            parents[int(stat.parent.name)] = int(stat.read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
    found, frontier = {root}, {root}
    while frontier:
        frontier = {pid for pid, ppid in parents.items() if ppid in frontier} - found
        found |= frontier
    return found & set(parents)


def processes_mentioning(text: str) -> set[int]:
    """Processes whose command line or environment contains ``text``."""
    hits, needle = set(), text.encode()
    for proc in Path("/proc").glob("[0-9]*"):
        for part in ("cmdline", "environ"):
            try:
                if needle in (proc / part).read_bytes():
                    hits.add(int(proc.name))
                    break
            except OSError:
                break
    return hits - {os.getpid()}


def kill(pids: set[int]) -> None:
    for pid in pids:
        try:
            os.kill(pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass


class LocalCompose:
    def __init__(self, compose_file: Path, env: dict[str, str], ports: dict[str, list[int]]):
        """``env``: the variables compose would read from ``.env``/the shell; ``ports``: the
        container ports each service listens on that others (or the test) reach."""
        self.file = compose_file
        self.env = dict(env)
        self.raw = yaml.safe_load(compose_file.read_text())
        self.services = interpolate(self.raw["services"], self.env)
        # Short: Ray's AF_UNIX socket paths live under each node's temp dir (107-byte limit).
        self.root = Path(tempfile.mkdtemp(prefix="nc", dir="/tmp"))
        self.ports = {(svc, p): free_port() for svc, plist in ports.items() for p in plist}
        self.procs: dict[str, subprocess.Popen] = {}
        self.replacements: dict[str, list[str]] = {}

    # ------------------------------------------------------------------------------- mapping

    def port(self, service: str, container_port: int) -> int:
        return self.ports[(service, container_port)]

    def url(self, service: str, container_port: int) -> str:
        return f"http://127.0.0.1:{self.port(service, container_port)}"

    def _localise(self, text: str, service: str) -> str:
        for (svc, cport), local in self.ports.items():
            text = re.sub(rf"\b{re.escape(svc)}:{cport}\b", f"127.0.0.1:{local}", text)
            if svc == service:  # the service's own listening port and its health check
                text = re.sub(rf"(--port[ =]){cport}\b", rf"\g<1>{local}", text)
                text = re.sub(rf"\b127\.0\.0\.1:{cport}\b", f"127.0.0.1:{local}", text)
        text = text.replace("0.0.0.0", "127.0.0.1")
        return re.sub(r"\bray start\b", " ".join(["ray start", *RAY_LOCAL]), text)

    def command(self, service: str, key: str = "command") -> list[str]:
        value = self.services[service][key]
        if key == "healthcheck":
            value = value["test"][1:]  # ["CMD", ...]
        argv = [value] if isinstance(value, str) else list(value)
        if argv[:2] == ["ray", "start"]:  # exec form; in "sh -c" strings _localise adds them
            argv = argv[:2] + RAY_LOCAL + argv[2:]
        for i in range(1, len(argv)):  # exec form "--port", "6379": the service's own port
            if argv[i - 1] == "--port" and (service, int(argv[i])) in self.ports:
                argv[i] = str(self.port(service, int(argv[i])))
        return self._resolve([self._localise(a, service) for a in argv])

    @staticmethod
    def _resolve(argv: list[str]) -> list[str]:
        """Programs from this virtualenv (the image's PATH); ``sh -c`` strings keep the names, and
        PATH points there."""
        return [str(BIN / argv[0]) if (BIN / argv[0]).exists() else argv[0], *argv[1:]]

    def environment(self, service: str, replica: int = 0) -> dict[str, str]:
        env = {k: v for k, v in os.environ.items()
               if not k.startswith(("NEUENH_", "RAY_", "AWS_"))}  # nothing of the developer's
        env["PATH"] = f"{BIN}{os.pathsep}{env.get('PATH', '')}"
        for k, v in (self.services[service].get("environment") or {}).items():
            env[k] = self._localise(str(v), service)
        home = self.root / f"{service}-{replica}"
        (home / "tmp").mkdir(parents=True, exist_ok=True)
        env["RAY_TMPDIR"] = str(home / "tmp")
        env["HOME"] = str(home)  # Ray reads ~/.ray (tokens); a container has its own home
        return env

    def volume_dir(self, service: str, container_path: str) -> Path:
        path = self.root / f"{service}-volume{container_path.replace('/', '-')}"
        path.mkdir(parents=True, exist_ok=True)
        return path

    # ----------------------------------------------------------------------------- processes

    def replace(self, service: str, argv: list[str]) -> None:
        """Run ``argv`` instead of the service's command (its image is not available here)."""
        self.replacements[service] = argv

    def start(self, service: str, replica: int = 0, env: dict[str, str] | None = None,
              paths: dict[str, Path] | None = None) -> subprocess.Popen:
        """Start one replica; ``paths`` maps container paths (volumes) in the command and
        environment to local directories."""
        argv = self.replacements.get(service) or self.command(service)
        environment = {**self.environment(service, replica), **(env or {})}
        for container, local in (paths or {}).items():
            argv = [a.replace(container, str(local)) for a in argv]
            environment = {k: v.replace(container, str(local)) for k, v in environment.items()}
        name = f"{service}-{replica}"
        log = open(self.root / f"{name}.log", "wb")
        proc = subprocess.Popen(argv, env=environment, stdout=log, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, start_new_session=True,
                                cwd=self.root / f"{service}-{replica}")
        log.close()
        self.procs[name] = proc
        return proc

    def run(self, service: str, timeout: float = 60, key: str = "command") -> subprocess.CompletedProcess:
        """Run a one-shot service (or a service's health check, ``key="healthcheck"``) to its end."""
        return subprocess.run(self.command(service, key), env=self.environment(service), capture_output=True,
                              text=True, timeout=timeout, cwd=self.root)

    def healthy(self, service: str, timeout: float) -> None:
        deadline, last = time.monotonic() + timeout, None
        while time.monotonic() < deadline:
            for name, proc in self.procs.items():
                if name.startswith(service + "-") and proc.poll() is not None:
                    raise AssertionError(f"{name} exited {proc.returncode}:\n{self.log(name)}")
            last = self.run(service, key="healthcheck")
            if last.returncode == 0:
                return
            time.sleep(1)
        raise AssertionError(f"{service} not healthy after {timeout} s: {last.stdout}{last.stderr}")

    def wait_log(self, name: str, text: str, timeout: float) -> None:
        """Until ``text`` appears in a replica's output (e.g. Ray's "Ray runtime started")."""
        deadline = time.monotonic() + timeout
        while text not in self.log(name, tail=None):
            if self.procs[name].poll() is not None or time.monotonic() > deadline:
                raise AssertionError(f"{name}: no {text!r} after {timeout} s:\n{self.log(name)}")
            time.sleep(0.25)

    def log(self, name: str, tail: int | None = 5000) -> str:
        path = self.root / f"{name}.log"
        text = path.read_text(errors="replace") if path.exists() else ""
        return text[-tail:] if tail else text

    def kill_node(self, name: str) -> set[int]:
        """SIGKILL a replica and everything it started, at once (a container killed)."""
        pids = process_tree(self.procs[name].pid) | processes_mentioning(str(self.root / name) + "/")
        kill(pids)
        self.procs[name].wait(10)
        return pids

    def close(self) -> None:
        for name, proc in self.procs.items():  # a clean stop first: the api shuts Ray down
            if proc.poll() is None:
                stand_in = name.rsplit("-", 1)[0] in self.replacements  # nothing to shut down
                try:
                    os.killpg(proc.pid, signal.SIGKILL if stand_in else signal.SIGTERM)
                except ProcessLookupError:
                    pass
        deadline = time.monotonic() + 5  # then SIGKILL, as `docker compose down` does after its grace
        while time.monotonic() < deadline and any(p.poll() is None for p in self.procs.values()):
            time.sleep(0.2)
        for _ in range(20):  # Ray's daemons outlive their starters: kill until none is left
            # only unreaped children by pid (a reaped one's pid may belong to someone else now)
            pids = set().union(*(process_tree(p.pid) for p in self.procs.values() if p.poll() is None)) \
                | processes_mentioning(str(self.root) + "/")
            if not pids:
                break
            kill(pids)
            time.sleep(0.25)
        for proc in self.procs.values():
            proc.poll()
        shutil.rmtree(self.root, ignore_errors=True)
