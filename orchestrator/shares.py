"""Fair shares of the cluster between the jobs running at once.

Every running job that trains candidates asks ``FairShare.limit`` how many of its candidates may be
in flight, telling how many it still wants to run. The cluster's CPUs (and GPUs, for jobs that ask
for them) are divided by max-min fairness ("water filling"): a job that wants less than an equal
share gets what it wants, the rest is split equally among the others. So no job starves another,
no slot idles while a job still waits for one, and the shares re-balance as jobs start and end:
a job over its share submits nothing new until enough of its candidates finish (running candidates
are never pre-empted). A job always may have one candidate in flight, so every job progresses
however many run.

Thread-safe: each running job's thread calls ``limit`` from its executor loop.
"""

from __future__ import annotations

import math
import threading
import time
from typing import Callable

from .executor import Resources


def water_fill(capacity: float, demands: dict[str, float]) -> dict[str, float]:
    """Max-min fair split of ``capacity`` among ``demands`` (each job gets at most its demand)."""
    shares: dict[str, float] = {}
    left, waiting = max(0.0, capacity), sorted(demands, key=lambda j: (demands[j], j))
    while waiting:
        equal = left / len(waiting)
        smallest = waiting[0]
        if demands[smallest] > equal:
            shares.update({j: equal for j in waiting})
            break
        shares[smallest] = demands[smallest]
        left -= demands[smallest]
        waiting.pop(0)
    return shares


class FairShare:
    def __init__(self, capacity: Callable[[], tuple[float, float]], refresh_s: float = 2.0):
        """``capacity()`` is the cluster's (CPUs, GPUs) now; it is read at most every ``refresh_s``
        seconds (a cluster that grows or loses a node is seen within that)."""
        self._capacity, self._refresh_s = capacity, refresh_s
        self._lock = threading.Lock()
        self._wanting: dict[str, tuple[int, Resources]] = {}  # job -> candidates it wants running
        self._cached: tuple[float, float] | None = None
        self._read_at = -math.inf

    def limit(self, job_id: str, resources: Resources, wanting: int) -> int:
        """How many of ``job_id``'s candidates may be in flight, now that it wants ``wanting`` (its
        unfinished candidates: in flight and not yet submitted). At least 1 while it wants any."""
        if wanting <= 0:
            self.leave(job_id)
            return 0
        with self._lock:
            self._wanting[job_id] = (wanting, resources)
            cpus, gpus = self._cluster()
            allowed = wanting
            for capacity, ask in ((cpus, lambda r: r.cpus), (gpus, lambda r: r.gpus)):
                if ask(resources) <= 0:
                    continue
                demands = {j: n * ask(r) for j, (n, r) in self._wanting.items() if ask(r) > 0}
                share = water_fill(capacity, demands)[job_id]
                allowed = min(allowed, math.floor(share / ask(resources) + 1e-9))
            return max(1, allowed)

    def leave(self, job_id: str) -> None:
        """``job_id`` wants nothing now (between rounds, or ended): its share goes to the others."""
        with self._lock:
            self._wanting.pop(job_id, None)

    def _cluster(self) -> tuple[float, float]:
        now = time.monotonic()
        if self._cached is None or now - self._read_at >= self._refresh_s:
            self._cached, self._read_at = self._capacity(), now
        return self._cached
