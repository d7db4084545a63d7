"""The Ray executor: one Ray task per candidate (ARCHITECTURE §3).

* The training data is put in the object store once per job, each round's parent bundle once per
  round; tasks receive references, so nothing is copied per candidate on a node.
* Each task asks for the job's ``cpus_per_candidate`` (and fractional ``gpus_per_candidate``) and
  runs torch with that many threads. Before a round the executor asks the cluster for the round's
  parallelism (``ray.autoscaler.sdk.request_resources``, summed over the jobs training at once), so
  a larger radius runs on more workers where the cluster can grow; what does not fit is queued by
  Ray. Each job keeps at most its ``limit`` of candidates in flight (its fair share).
* A worker process or node that dies is retried (``max_retries``); a task that raises or diverges
  comes back as a failed report and the round goes on.
* Embedded default: a local Ray with bounded object-store memory and no dashboard. With
  ``address`` (or ``RAY_ADDRESS``) it joins an existing cluster instead.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
import time
from typing import Callable, Iterator

import ray
from ray.autoscaler.sdk import request_resources
from ray.exceptions import RayError

from neuenh.allocator import keep_freed_memory
from neuenh.train import TrainConfig

from neuenh.data.samples import TrainingData
from neuenh_service.orchestrator.executor import (CandidateReport, CandidateTask, ClusterInfo, Executor, InFlight, NodeInfo,
                                   TrainRequest, unlimited)

from .candidate import run_candidate


@ray.remote
def _train_candidate(parent: bytes, data: TrainingData, task: CandidateTask, config: TrainConfig,
                     threads: int) -> CandidateReport:
    import torch

    torch.set_num_threads(threads)
    keep_freed_memory()  # training and fit scores reuse their freed activations (neuenh.allocator)
    node = ray.get_runtime_context().get_node_id()
    return run_candidate(parent, data, task, config, node=node)


@contextlib.contextmanager
def _keeping_signal_handlers():
    """``ray.init`` replaces the SIGTERM handler with one that exits at once; the process that
    embeds Ray (uvicorn in ``neuenh serve``) owns its signals and shuts down in its own order."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    saved = {sig: signal.getsignal(sig) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        yield
    finally:
        for sig, handler in saved.items():
            if handler is not None:
                signal.signal(sig, handler)


class RayExecutor(Executor):
    def __init__(
        self,
        *,
        address: str | None = None,
        num_cpus: int | None = None,
        object_store_memory: int = 512 * 1024**2,
        max_retries: int = 3,
        poll_s: float = 0.25,
    ):
        self.max_retries = max_retries
        self.poll_s = poll_s
        self._owns_ray = False
        self._in_flight = InFlight()
        self._demand: dict[str, list[dict[str, float]]] = {}  # per job: the bundles its round asks for
        self._demand_lock = threading.Lock()
        self.address = address or os.environ.get("RAY_ADDRESS") or None
        if not ray.is_initialized():
            with _keeping_signal_handlers():
                if self.address:
                    ray.init(address=self.address, log_to_driver=False)
                else:
                    # "local": a Ray of its own even when `ray start` ran on this machine — without
                    # it ray.init joins the cluster /tmp/ray/ray_current_cluster names, and then
                    # refuses num_cpus and object_store_memory (a colleague's cluster broke `serve`)
                    ray.init(address="local", num_cpus=num_cpus, object_store_memory=object_store_memory,
                             include_dashboard=False, log_to_driver=False)
            self._owns_ray = True

    def put_dataset(self, data: TrainingData) -> ray.ObjectRef:
        return ray.put(data)

    def train(self, request: TrainRequest, cancelled: Callable[[], bool] = lambda: False,
              limit: Callable[[int], int] = unlimited) -> Iterator[CandidateReport]:
        dataset, tasks, config, resources, owner = (request.dataset, request.tasks, request.config,
                                                    request.resources, request.owner)
        bundle = {"CPU": resources.cpus, **({"GPU": resources.gpus} if resources.gpus else {})}
        with self._demand_lock:
            self._demand[owner] = [bundle] * len(tasks)
            request_resources(bundles=[b for job in self._demand.values() for b in job])
        parent_refs = [ray.put(p) for p in request.parents]
        threads = max(1, int(resources.cpus))
        remote = _train_candidate.options(num_cpus=resources.cpus, num_gpus=resources.gpus,
                                          max_retries=self.max_retries)
        waiting, pending = list(tasks), {}
        try:
            while waiting or pending:
                if cancelled():
                    for ref in pending:
                        ray.cancel(ref, force=True)
                    return
                allowed = limit(len(waiting) + len(pending))
                while waiting and len(pending) < allowed:
                    t = waiting.pop(0)
                    pending[remote.remote(parent_refs[t.parent], dataset, t, config, threads)] = t
                self._in_flight.set(owner, len(pending), resources)
                if not pending:  # over its share: wait for another job's candidates to finish
                    time.sleep(self.poll_s)
                    continue
                ready, _ = ray.wait(list(pending), num_returns=1, timeout=self.poll_s)
                for ref in ready:
                    task = pending.pop(ref)
                    self._in_flight.set(owner, len(pending), resources)
                    try:
                        yield ray.get(ref)
                    except RayError as exc:  # the worker or its node died beyond retries
                        yield CandidateReport(task, float("nan"), float("nan"), 0, 0.0, "unknown",
                                              error=f"worker lost: {type(exc).__name__}: {exc}".splitlines()[0])
        finally:
            self._in_flight.set(owner, 0, resources)
            with self._demand_lock:
                self._demand.pop(owner, None)
                request_resources(bundles=[b for job in self._demand.values() for b in job])

    def cluster(self) -> ClusterInfo:
        nodes = tuple(
            NodeInfo(id=n["NodeID"], address=n.get("NodeManagerAddress"), alive=bool(n.get("Alive")),
                     cpus=float(n.get("Resources", {}).get("CPU", 0.0)),
                     gpus=float(n.get("Resources", {}).get("GPU", 0.0)),
                     memory_bytes=int(n["Resources"]["memory"]) if "memory" in n.get("Resources", {}) else None)
            for n in ray.nodes())
        total, free = ray.cluster_resources(), ray.available_resources()
        return ClusterInfo(backend="ray", address=self.address, nodes=nodes,
                           cpus=total.get("CPU", 0.0), gpus=total.get("GPU", 0.0),
                           cpus_available=free.get("CPU", 0.0), gpus_available=free.get("GPU", 0.0),
                           busy_candidates=self._in_flight.candidates, holders=self._in_flight.holders())

    def close(self) -> None:
        if self._owns_ray and ray.is_initialized():
            ray.shutdown()
            self._owns_ray = False
