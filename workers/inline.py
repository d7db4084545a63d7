"""In-process executor: trains candidates one after another in the calling thread.

For fast unit tests of the orchestrator only; the service and ``neuenh search`` use Ray.
"""

from __future__ import annotations

from typing import Callable, Iterator, Sequence

from neuenh.train import TrainConfig, TrainingData
from orchestrator.executor import CandidateReport, CandidateTask, Executor, Resources

from .candidate import run_candidate


class InlineExecutor(Executor):
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
            yield run_candidate(parents[task.parent], dataset, task, config, node="inline")
