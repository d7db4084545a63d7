"""The benchmarks' timing harness: one way to wait for a quiet machine, time cases side by side,
and describe the machine a number was measured on.

* ``Background`` measures how much CPU the rest of the machine used over an interval (``/proc/stat``
  minus this process), so a repeat disturbed by someone else's work can be thrown away and redone;
* ``wait_quiet`` waits (bounded) until the rest of the machine is idle;
* ``Timer.measure`` times several cases interleaved, repeat by repeat in rotating order, and
  reports the median of the undisturbed repeats: ratios measured this way hold on a shared machine;
* ``fitting_process()`` makes this process fit as ``neuenh fit``'s do;
* ``machine()`` is the machine, torch and git revision a section records.
"""

from __future__ import annotations

import datetime as dt
import json
import math
import os
import platform
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

ROOT = Path(__file__).resolve().parents[1]


class Background:
    """CPU (in cores) the rest of the machine used between ``start`` and ``stop``; ``other_own_cpu``
    (CPU seconds so far of processes working for this one that it has not waited for, e.g. render
    workers) counts as this process's own."""

    _tick = os.sysconf("SC_CLK_TCK")

    def __init__(self, other_own_cpu: Callable[[], float] | None = None):
        self.other_own_cpu = other_own_cpu

    @staticmethod
    def _busy() -> float:
        try:
            with open("/proc/stat") as f:
                fields = [int(v) for v in f.readline().split()[1:]]
        except OSError:
            return math.nan
        idle = fields[3] + (fields[4] if len(fields) > 4 else 0)
        return (sum(fields[:8]) - idle) / Background._tick

    def _own(self) -> float:
        usage = resource.getrusage(resource.RUSAGE_SELF)
        children = resource.getrusage(resource.RUSAGE_CHILDREN)
        other = self.other_own_cpu() if self.other_own_cpu else 0.0
        return usage.ru_utime + usage.ru_stime + children.ru_utime + children.ru_stime + other

    def start(self) -> "Background":
        self.t, self.busy, self.own = time.perf_counter(), self._busy(), self._own()
        return self

    def stop(self) -> float:
        wall = max(time.perf_counter() - self.t, 1e-9)
        return max(0.0, (self._busy() - self.busy) - (self._own() - self.own)) / wall


def fitting_process() -> None:
    """This process as the ``neuenh`` command and the service's workers run fits and training: one torch
    thread and one Dr.Jit thread (the latent fit's kernel; no Mitsuba may run in it then), freed memory
    kept for the next step (``neuenh.allocator``)."""
    from neuenh.allocator import keep_freed_memory
    from neuenh.fit.jit import set_fit_threads

    set_fit_threads(1)
    keep_freed_memory()


def status_bytes(field: str) -> int:
    """A memory figure of this process from ``/proc/self/status`` (``VmRSS``, ``VmHWM``: the peak), in bytes."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) * 1024  # kB
    raise RuntimeError(f"/proc/self/status has no {field}")


def wait_quiet(max_wait: float, threshold: float, seconds: int = 3) -> float:
    """Wait (at most ``max_wait`` s) until the rest of the machine used less than ``threshold``
    cores for ``seconds`` consecutive seconds; returns the waiting time."""
    start, quiet = time.perf_counter(), 0
    while quiet < seconds and time.perf_counter() - start < max_wait:
        probe = Background().start()
        time.sleep(1.0)
        quiet = quiet + 1 if probe.stop() < threshold else 0
    return time.perf_counter() - start


@dataclass
class Timing:
    seconds: float  # median per call
    repeats: int
    rejected: int
    background: float  # median background load (cores) over the kept repeats


@dataclass
class Timer:
    """Interleaved medians. A repeat during which the rest of the machine used more than
    ``max_background`` cores is redone (after a pause), up to ``6 × repeats`` attempts; after that
    a busy machine still gets numbers, with their background load recorded."""

    repeats: int
    min_time: float
    max_background: float
    other_own_cpu: Callable[[], float] | None = None  # see Background
    rejected: int = 0
    backgrounds: list[float] = field(default_factory=list)

    def measure(self, cases: dict[str, Callable[[], object]], warmup: int = 2) -> dict[str, Timing]:
        """Median seconds per call of every case, measured interleaved (rotating order)."""
        for fn in cases.values():
            for _ in range(warmup):
                fn()
        inner = {}
        for name, fn in cases.items():
            t = time.perf_counter()
            fn()
            inner[name] = max(1, math.ceil(self.min_time / max(time.perf_counter() - t, 1e-6)))
        times: dict[str, list[float]] = {name: [] for name in cases}
        loads: dict[str, list[float]] = {name: [] for name in cases}
        rejected = dict.fromkeys(cases, 0)
        names = list(cases)
        attempts = 0
        while min(len(v) for v in times.values()) < self.repeats:
            attempts += 1
            order = names[attempts % len(names):] + names[: attempts % len(names)]
            for name in order:
                if len(times[name]) >= self.repeats:
                    continue
                probe = Background(self.other_own_cpu).start()
                t = time.perf_counter()
                for _ in range(inner[name]):
                    cases[name]()
                elapsed = (time.perf_counter() - t) / inner[name]
                load = probe.stop()
                if load > self.max_background and attempts < 6 * self.repeats:
                    rejected[name] += 1
                    time.sleep(1.0)
                    continue
                times[name].append(elapsed)
                loads[name].append(load)
        out = {}
        for name in cases:
            self.rejected += rejected[name]
            self.backgrounds.extend(loads[name])
            out[name] = Timing(statistics.median(times[name]), len(times[name]), rejected[name],
                               statistics.median(loads[name]))
        return out

    def method(self) -> str:
        """One sentence for a section: how the numbers were taken and how disturbed they were."""
        background = statistics.median(self.backgrounds) if self.backgrounds else math.nan
        return (f"medians of {self.repeats} interleaved repeats after a warm-up; repeats during which the "
                f"rest of the machine used more than {self.max_background} cores were redone "
                f"({self.rejected} redone; median background load of the kept ones {background:.2f} cores)")


def output_arguments(parser) -> None:
    """The options every side-by-side bench takes: ``--json`` (the raw numbers), ``--write`` (the
    section of docs/BENCHMARKS.md it replaces) and ``--max-wait`` (for a quiet machine, seconds)."""
    parser.add_argument("--json", type=Path, help="write the raw numbers here")
    parser.add_argument("--write", metavar="PATH", help="write/replace this section of PATH (docs/BENCHMARKS.md)")
    parser.add_argument("--max-wait", type=float, default=300.0)


def absent(path: Path, what: str) -> bool:
    """True, after printing that the bench skips, when ``path`` (``what`` names it) does not exist."""
    if Path(path).exists():
        return False
    print(f"skipped: {path} is absent ({what})")
    return True


def write_json(path: Path, data) -> None:
    """``data`` as indented JSON at ``path``, atomically (``neuenh.files``). A bench run by
    ``run_at_revision`` in a checkout older than that module writes plainly: its parent reads the
    file only once it has exited."""
    text = json.dumps(data, indent=1)
    try:
        from neuenh.files import atomic_write
    except ImportError:
        Path(path).write_text(text)
    else:
        atomic_write(path, text)


def run_at_revision(rev: str, script: Path, argv: list[str]) -> dict:
    """``script`` (this checkout's copy of a bench) run with ``argv`` in the repository as it was at
    ``rev`` (``git archive`` to a temporary folder), so the same measurement runs on the older code
    in the same session; returns the JSON it writes (``--json``; ``--max-wait 0``: this process waited).
    This file goes along with the script (it imports nothing of ``neuenh``); the rest is ``rev``'s."""
    repo = Path(__file__).resolve().parents[1]
    with tempfile.TemporaryDirectory(prefix="bench-before-") as tmp:
        checkout = Path(tmp) / "checkout"
        checkout.mkdir()
        archive = subprocess.run(["git", "-C", str(repo), "archive", rev], check=True, capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", str(checkout)], input=archive, check=True)
        copy = checkout / "bench" / script.name
        copy.write_text(script.read_text())
        (checkout / "bench" / "harness.py").write_text(Path(__file__).read_text())
        out = Path(tmp) / "before.json"
        subprocess.run([sys.executable, str(copy), *argv, "--json", str(out), "--max-wait", "0"], check=True)
        return json.loads(out.read_text())


def side_by_side(args, script: Path, run: Callable[[bool], Any], before_argv: list[str],
                 section: Callable[[dict, Any, Any, str], str], title: str, argv: list[str] | None) -> None:
    """A bench's numbers beside those of the revision ``args.before_rev`` names, measured in the same run,
    published. Inside that revision's checkout (``args.before``, the flag ``run_at_revision`` passes on):
    ``run(True)`` written to ``args.json``, nothing else. Else ``script`` run there first with ``--before``
    and ``before_argv`` (``before`` None without ``--before-rev``), then ``now = run(False)``, both written
    to ``args.json`` when given, and ``section(machine(), now, before, command)`` published under ``title``
    (``report.publish``; ``--write``), ``command`` the bench's command line (``argv``, default sys.argv's)."""
    from bench.report import publish  # here: this module imports nothing of neuenh (run_at_revision)

    if args.before:
        write_json(args.json, run(True))
        return
    env = machine()
    before = run_at_revision(args.before_rev, script, ["--before", *before_argv]) if args.before_rev else None
    now = run(False)
    if args.json:
        write_json(args.json, {"now": now, "before": before})
    command = " ".join([f"python bench/{script.name}", *(argv if argv is not None else sys.argv[1:])])
    publish(section(env, now, before, command).splitlines(), args.write, title)


def cpu_info() -> dict:
    """Model, cores, vendor/family, flags and clock of this CPU (lscpu and /proc/cpuinfo)."""
    info = {"model": platform.processor() or "unknown", "cores": os.cpu_count() or 1}
    try:
        text = subprocess.run(["lscpu"], capture_output=True, text=True, check=True).stdout
        fields = dict(line.split(":", 1) for line in text.splitlines() if ":" in line)
        fields = {k.strip(): v.strip() for k, v in fields.items()}
        info["model"] = fields.get("Model name", info["model"])
        info["family"] = int(fields.get("CPU family", "0") or 0)
        info["model_number"] = int(fields.get("Model", "0") or 0)
        info["vendor"] = fields.get("Vendor ID", "")
        info["threads_per_core"] = int(fields.get("Thread(s) per core", "1") or 1)
    except (OSError, subprocess.CalledProcessError, ValueError):
        pass
    try:
        cpuinfo = Path("/proc/cpuinfo").read_text()
        info["flags"] = set(re.search(r"^flags\s*:(.*)$", cpuinfo, re.M).group(1).split())
        info["mhz"] = float(re.search(r"^cpu MHz\s*:\s*([\d.]+)", cpuinfo, re.M).group(1))
    except (OSError, AttributeError):
        info["flags"], info["mhz"] = set(), math.nan
    return info


def machine() -> dict:
    """The machine, software and revision a section records."""
    import torch

    info = cpu_info()
    try:
        git = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                             text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        git = "unknown"
    try:
        ram = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    except (ValueError, OSError):
        ram = math.nan
    return {
        "date": dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "cpu": info["model"], "cores": info["cores"], "threads_per_core": info.get("threads_per_core", 1),
        "ram_gib": ram, "python": platform.python_version(), "torch": torch.__version__,
        "threads": torch.get_num_threads(), "git": git, "isa": vector_isa(),
    }


def vector_isa() -> str:
    """The vector instructions torch's CPU kernels use here (its dispatch level), and bfloat16
    arithmetic where the CPU has it (``neuenh.train.native_bfloat16``): these machines differ in both
    (AVX2 alone, AVX-512 with BF16, AMX), and speeds only compare between runs on the same."""
    import torch

    from neuenh.train import native_bfloat16

    return torch.backends.cpu.get_cpu_capability() + (" with bfloat16" if native_bfloat16() else "")


def machine_line(env: dict) -> str:
    """``Machine: ...`` for a section."""
    isa = f" ({env['isa']})" if env.get("isa") else ""  # records written before it was kept have none
    return (f"Machine: {env['cpu']}{isa}, {env['cores']} logical CPUs, {env['ram_gib']:.0f} GiB; Python "
            f"{env['python']}, torch {env['torch']} ({env['threads']} threads); git {env['git']}")


def fmt_rate(x: float) -> str:
    return f"{x / 1e6:.2f} M/s" if x >= 1e6 else f"{x / 1e3:.0f} K/s"
