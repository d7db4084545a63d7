"""What the API accepts and returns. Storage records never leave the service directly: every
response is one of these ``*Public`` models, built from a record by its ``from_record``."""

from __future__ import annotations

import dataclasses

from datetime import datetime, timezone
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from orchestrator.runner import Progress
from orchestrator.spec import JobSpec
from storage import CandidateRecord, JobRecord, JobStatus, RoundRecord


def _time(t: float | None) -> datetime | None:
    return None if t is None else datetime.fromtimestamp(t, tz=timezone.utc)


class JobCreate(JobSpec):
    """A search job spec (DESIGN §4), submitted as the JSON body of ``POST /v1/jobs``."""


class Links(BaseModel):
    self: str
    history: str
    model: str
    cancel: str


class ProgressPublic(BaseModel):
    """Live progress of the job the worker is running (not persisted; gone after a restart)."""

    round: int
    done: int
    total: int
    best_val_loss: float | None
    state: str
    elapsed_s: float
    message: str

    @classmethod
    def from_progress(cls, p: Progress) -> "ProgressPublic":
        return cls.model_validate(dataclasses.asdict(p))  # job_id and status are not repeated here


class JobPublic(BaseModel):
    id: str
    name: str | None
    model: str
    status: JobStatus
    terminal: bool
    error: str | None
    created_at: datetime
    updated_at: datetime
    last_round: int | None = Field(description="index of the last committed round; null before round 0")
    current_state: str | None = Field(description="state of the last committed winner (B_c)")
    spec: dict[str, Any]
    progress: ProgressPublic | None = None
    links: Links
    positions: list[str] = Field(default_factory=list,
                                 description="the model's position names, one per digit of a state string")

    @classmethod
    def from_record(cls, job: JobRecord, base: str = "/v1", progress: Progress | None = None) -> "JobPublic":
        from neuenh.models import get_model  # builds a small graph: ~50 us, no cache needed

        url = f"{base}/jobs/{job.id}"
        model = job.spec.get("model", "ggx")
        return cls(
            id=job.id, name=job.spec.get("name"), model=model, positions=list(get_model(model).positions),
            status=job.status,
            terminal=job.terminal, error=job.error, created_at=_time(job.created_at),
            updated_at=_time(job.updated_at), last_round=job.last_round,
            current_state=job.current_state, spec=job.spec,
            progress=ProgressPublic.from_progress(progress) if progress and not job.terminal else None,
            links=Links(self=url, history=f"{url}/history", model=f"{url}/model", cancel=f"{url}/cancel"),
        )


class JobList(BaseModel):
    jobs: list[JobPublic]
    next_cursor: str | None = Field(description="pass as ?cursor= for the next page; null on the last")


class CandidatePublic(BaseModel):
    state: str
    ok: bool
    winner: bool
    train_loss: float | None
    val_loss: float | None
    epochs: int
    wall_s: float
    node: str | None
    error: str | None
    seed: int | None

    @classmethod
    def from_record(cls, c: CandidateRecord, winner_state: str) -> "CandidatePublic":
        return cls(state=c.state, ok=c.ok, winner=c.state == winner_state, train_loss=c.train_loss,
                   val_loss=c.val_loss, epochs=c.epochs, wall_s=c.wall_s, node=c.node, error=c.error,
                   seed=c.seed)


class RoundPublic(BaseModel):
    round: int
    parent_state: str
    winner_state: str
    winner_val_loss: float
    converged: bool = Field(description="the stay candidate won: the search stopped here (false for the "
                                        "polish round, extra.polish, that may follow)")
    started_at: datetime
    finished_at: datetime
    wall_s: float
    candidates: list[CandidatePublic]
    extra: dict[str, Any]

    @classmethod
    def from_record(cls, r: RoundRecord) -> "RoundPublic":
        return cls(round=r.index, parent_state=r.parent_state, winner_state=r.winner_state,
                   winner_val_loss=r.winner_val_loss, converged=r.winner_state == r.parent_state and not r.extra.get("polish"),
                   started_at=_time(r.started_at), finished_at=_time(r.finished_at),
                   wall_s=r.finished_at - r.started_at,
                   candidates=[CandidatePublic.from_record(c, r.winner_state) for c in r.candidates],
                   extra=r.extra)


class HistoryPublic(BaseModel):
    model_config = ConfigDict(json_schema_extra={"description": "Committed rounds, oldest first."})

    job_id: str
    status: JobStatus
    terminal: bool
    current_state: str | None
    rounds: list[RoundPublic]
    next_since_round: int = Field(description="poll again with ?since_round= this value")


class NodePublic(BaseModel):
    id: str
    address: str | None
    alive: bool
    cpus: float
    gpus: float
    memory_bytes: int | None


class ClusterPublic(BaseModel):
    """Where candidates train: the executor's nodes and what is free now."""

    backend: str = Field(description="'ray' (embedded or joined cluster) or 'inline' (in-process)")
    address: str | None = Field(description="the Ray cluster joined; null for an embedded or inline executor")
    nodes: list[NodePublic]
    cpus: float
    gpus: float
    cpus_available: float
    gpus_available: float
    busy_candidates: int = Field(description="candidates training right now")
    running_job: str | None = Field(description="the job the service is running, if any")


class FittedMaterial(BaseModel):
    name: str
    loss: float = Field(description="mean log-L1 of the fitted model on the uploaded measurements")
    samples: int
    params: dict[str, list[float]] = Field(description="fitted parameters by name (the latent code too "
                                                       "when the model uses it)")


class FitPublic(BaseModel):
    """Materials fitted with a job's model, its module weights frozen (``POST /v1/jobs/{id}/fit``)."""

    job_id: str
    round: int = Field(description="the committed round whose model was used")
    model: str
    state: str
    method: str
    epochs: int
    wall_s: float
    materials: list[FittedMaterial]


class ErrorPublic(BaseModel):
    """Every error answer: ``detail`` says in one line what is wrong."""

    detail: str
    errors: list[dict[str, Any]] | None = Field(
        None, description="for an invalid request: each problem with its location (loc, msg, type)")


class Health(BaseModel):
    status: str
    version: str
    worker_alive: bool
    auth: bool
