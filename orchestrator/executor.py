"""The Executor contract: how the orchestrator has candidates trained, without knowing by whom.

An executor receives the job's training data once (``put_dataset``), then batches of candidate
tasks (a ``TrainRequest``), each naming its parent bundle (bytes) by index so a round ships its
parent once. It yields
a ``CandidateReport`` per task as each finishes, in completion order. A task that raises or whose
loss is not finite comes back as a report with ``error`` set (the round goes on); an executor
retries a task whose worker died. When ``cancelled()`` turns true the executor stops the tasks
still running and stops yielding.

Several jobs may call ``train`` at once from their own threads. Each request names its ``owner`` (the
job) and keeps at most ``limit(unfinished)`` of its tasks in flight, asking again as tasks finish
(``orchestrator.shares.FairShare`` answers); ``cluster().holders`` says which job holds what.

Implementations: ``workers.ray_executor.RayExecutor`` (the real one) and
``workers.inline.InlineExecutor`` (in-process, for fast unit tests).
"""

from __future__ import annotations

import threading
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Callable, Iterator, Sequence

from neuenh.train import TrainConfig

from neuenh.data.samples import TrainingData


@dataclass(frozen=True)
class Resources:
    """What one candidate asks of the cluster (the job spec's ``resources``)."""

    cpus: float = 1.0
    gpus: float = 0.0


@dataclass(frozen=True)
class CandidateTask:
    state: str
    seed: int
    epochs: int
    parent: int = 0  # index into the ``parents`` of the batch


@dataclass(frozen=True)
class TrainRequest:
    """One batch of candidates for ``Executor.train``: the tasks, trained from ``parents[task.parent]``
    on ``dataset`` (``put_dataset``'s handle) with ``config`` (whose ``epochs`` each task's replaces),
    each asking ``resources`` of the cluster, on behalf of the job ``owner``."""

    dataset: object
    parents: Sequence[bytes]
    tasks: Sequence[CandidateTask]
    config: TrainConfig
    resources: Resources = Resources()
    owner: str = ""


@dataclass
class CandidateReport:
    task: CandidateTask
    train_loss: float
    val_loss: float
    epochs: int
    wall_s: float
    node: str
    error: str | None = None
    bundle: bytes | None = None  # the trained candidate, None when it failed
    fit_score: float | None = None  # on the held-out materials (neuenh.selection), when the job asks
    fit_score_s: float = 0.0  # the part of wall_s that scoring took

    @property
    def ok(self) -> bool:
        return self.error is None


@dataclass(frozen=True)
class NodeInfo:
    id: str
    address: str | None
    alive: bool
    cpus: float
    gpus: float
    memory_bytes: int | None = None


@dataclass(frozen=True)
class SlotHolder:
    """One job's candidates in flight on the cluster, and the resources they hold."""

    job_id: str
    candidates: int
    cpus: float
    gpus: float


class InFlight:
    """What each job has in flight, kept by an executor for ``ClusterInfo`` (thread-safe)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._jobs: dict[str, tuple[int, Resources]] = {}

    def set(self, owner: str, candidates: int, resources: Resources) -> None:
        with self._lock:
            if candidates:
                self._jobs[owner] = (candidates, resources)
            else:
                self._jobs.pop(owner, None)

    @property
    def candidates(self) -> int:
        with self._lock:
            return sum(n for n, _ in self._jobs.values())

    def holders(self) -> tuple[SlotHolder, ...]:
        with self._lock:
            return tuple(SlotHolder(job, n, n * r.cpus, n * r.gpus) for job, (n, r) in sorted(self._jobs.items()))



def unlimited(unfinished: int) -> int:
    """The default ``limit`` of ``Executor.train``: every task in flight at once."""
    return unfinished


@dataclass(frozen=True)
class ClusterInfo:
    """Where candidates train, as an executor sees it now (``GET /v1/cluster``)."""

    backend: str  # "ray" or "inline"
    address: str | None  # the cluster joined; None when embedded or in-process
    nodes: tuple[NodeInfo, ...]
    cpus: float
    gpus: float
    cpus_available: float
    gpus_available: float
    busy_candidates: int  # tasks submitted and not yet reported
    holders: tuple[SlotHolder, ...] = ()  # per job, what its in-flight candidates hold

    def missing(self, resources: "Resources") -> list[str]:
        """What one candidate asks that no alive node has (empty when some node could run it)."""
        alive = [n for n in self.nodes if n.alive]
        cpus = max((n.cpus for n in alive), default=0.0)
        gpus = max((n.gpus for n in alive if n.cpus >= resources.cpus), default=0.0)
        problems = []
        if resources.cpus > cpus:
            problems.append(f"cpus_per_candidate: {resources.cpus:g}, but the largest node of this cluster "
                            f"has {cpus:g} CPUs")
        if resources.gpus > gpus:
            problems.append(f"gpus_per_candidate: {resources.gpus:g}, but the largest node of this cluster "
                            f"has {gpus:g} GPUs")
        return problems


class Executor(ABC):
    @abstractmethod
    def put_dataset(self, data: TrainingData) -> object:
        """Make the data available to workers once; returns an opaque handle for ``train``."""

    @abstractmethod
    def train(self, request: TrainRequest, cancelled: Callable[[], bool] = lambda: False,
              limit: Callable[[int], int] = unlimited) -> Iterator[CandidateReport]:
        """Train every task of ``request``, at most ``limit(n)`` in flight while ``n`` are
        unfinished, until ``cancelled()`` (see the module doc)."""

    @abstractmethod
    def cluster(self) -> ClusterInfo:
        """The nodes and resources candidates train on; cheap enough to call on every request."""

    def close(self) -> None:
        """Release what the executor holds (cluster connections, worker processes)."""
