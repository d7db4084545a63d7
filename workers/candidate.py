"""What a worker runs for one candidate: a pure call of ``neuenh.selection.train_and_score`` (the
candidate trained, then scored on the held-out materials when the job asks) that turns every
outcome, exceptions included, into a ``CandidateReport``."""

from __future__ import annotations

import dataclasses
import socket
import time

from neuenh.checkpoint import Bundle
from neuenh.selection import train_and_score
from neuenh.train import TrainConfig
from neuenh.data.samples import TrainingData
from neuenh_service.orchestrator.executor import CandidateReport, CandidateTask


def run_candidate(
    parent: bytes, data: TrainingData, task: CandidateTask, config: TrainConfig, node: str | None = None
) -> CandidateReport:
    start = time.perf_counter()
    node = node or socket.gethostname()
    try:
        result = train_and_score(
            Bundle.from_bytes(parent), task.state, data, dataclasses.replace(config, epochs=task.epochs), task.seed
        )
    except Exception as exc:  # a candidate's failure must not end the round
        return CandidateReport(task, float("nan"), float("nan"), 0, time.perf_counter() - start, node,
                               error=f"{type(exc).__name__}: {exc}")
    return CandidateReport(
        task,
        result.train_loss,
        result.val_loss,
        result.epochs,
        result.wall_s,
        node,
        error=result.error,
        bundle=result.bundle.to_bytes() if result.ok else None,
        fit_score=result.fit_score,
        fit_score_s=result.fit_score_s,
    )
