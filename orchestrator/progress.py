"""What a progress display needs, sent to the orchestrator's ``on_progress`` as a job moves."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Progress:
    job_id: str
    status: str
    round: int  # the round in flight (-1 outside rounds)
    done: int  # candidates reported in the current phase
    total: int  # candidates of the current phase
    best_val_loss: float | None  # the lowest loss that selects (search.score: the val loss or the fit score)
    state: str  # the last state reported
    elapsed_s: float  # since the job's run started in this process
    message: str = ""  # the phase ("train", "warmup", "halving", "polish", ...) or what happened
    score: str = "val"  # what ``best_val_loss`` is (``SelectionScore.label``: "val" or "fit score")
