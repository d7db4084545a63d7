"""In-process executor: trains candidates one after another in the calling thread.

For fast unit tests of the orchestrator only; the service and ``neuenh search`` use Ray.
"""

from __future__ import annotations

import os
import socket
from typing import Callable, Iterator, Sequence

from neuenh.train import TrainConfig

from neuenh.data.samples import TrainingData
from orchestrator.executor import CandidateReport, CandidateTask, ClusterInfo, Executor, NodeInfo, Resources

from .candidate import run_candidate


class InlineExecutor(Executor):
    busy = 0  # the candidate training in the calling thread, if any

    def put_dataset(self, data: TrainingData) -> TrainingData:
        return data

    def train(
        self,
        dataset: TrainingData,
        parents: Sequence[bytes],
        tasks: Sequence[CandidateTask],
        config: TrainConfig,
        resources: Resources = Resources(),
        cancelled: Callable[[], bool] = lambda: False,
    ) -> Iterator[CandidateReport]:
        for task in tasks:
            if cancelled():
                return
            self.busy = 1
            try:
                report = run_candidate(parents[task.parent], dataset, task, config, node="inline")
            finally:
                self.busy = 0
            yield report

    def cluster(self) -> ClusterInfo:
        cpus = float(os.cpu_count() or 1)
        node = NodeInfo(id="inline", address=socket.gethostname(), alive=True, cpus=cpus, gpus=0.0)
        return ClusterInfo(backend="inline", address=None, nodes=(node,), cpus=cpus, gpus=0.0,
                           cpus_available=cpus - self.busy, gpus_available=0.0, busy_candidates=self.busy)
