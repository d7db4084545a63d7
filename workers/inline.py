"""In-process executor: trains candidates one after another in the calling thread.

For fast unit tests of the orchestrator only; the service and ``neuenh search`` use Ray.
"""

from __future__ import annotations

import os
import socket
from typing import Callable, Iterator


from neuenh.data.samples import TrainingData
from neuenh_service.orchestrator.executor import (CandidateReport, ClusterInfo, Executor, InFlight, NodeInfo, TrainRequest,
                                   unlimited)

from .candidate import run_candidate


class InlineExecutor(Executor):
    def __init__(self) -> None:
        self._in_flight = InFlight()  # the candidate training in a calling thread, per job

    def put_dataset(self, data: TrainingData) -> TrainingData:
        return data

    def train(self, request: TrainRequest, cancelled: Callable[[], bool] = lambda: False,
              limit: Callable[[int], int] = unlimited) -> Iterator[CandidateReport]:
        r = request
        for i, task in enumerate(r.tasks):  # one at a time: within any limit (which is at least 1)
            if cancelled():
                return
            limit(len(r.tasks) - i)
            self._in_flight.set(r.owner, 1, r.resources)
            try:
                report = run_candidate(r.parents[task.parent], r.dataset, task, r.config, node="inline")
            finally:
                self._in_flight.set(r.owner, 0, r.resources)
            yield report

    def cluster(self) -> ClusterInfo:
        cpus = float(os.cpu_count() or 1)
        node = NodeInfo(id="inline", address=socket.gethostname(), alive=True, cpus=cpus, gpus=0.0)
        holders = self._in_flight.holders()
        busy = sum(h.cpus for h in holders)
        return ClusterInfo(backend="inline", address=None, nodes=(node,), cpus=cpus, gpus=0.0,
                           cpus_available=cpus - busy, gpus_available=0.0,
                           busy_candidates=self._in_flight.candidates, holders=holders)
