"""What the API accepts and returns. Storage records never leave the service directly: every
response is one of these ``*Public`` models, built from a record by its ``from_record``."""

from __future__ import annotations

import dataclasses
import functools
import json

from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from neuenh.search import describe_change
from neuenh_service.orchestrator.progress import Progress
from neuenh_service.orchestrator.spec import JobSpec
from neuenh_service.storage import (CandidateRecord, JobRecord, JobStatus, PlanRecord, PlanStatus, RoundKind, RoundRecord,
                     WarmupRecord, start_val_loss)


def _time(t: float | None) -> datetime | None:
    return None if t is None else datetime.fromtimestamp(t, tz=timezone.utc)


def _gain(val_loss: float, start: float | None) -> float | None:
    """The share of the starting state's validation loss removed (negative when it grew)."""
    return None if start is None else 1.0 - val_loss / start


class JobCreate(JobSpec):
    """A search job spec (ARCHITECTURE §4), submitted as the JSON body of ``POST /v1/jobs``."""


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
    score: str = Field("val", description="what best_val_loss is: the job's selecting loss, 'val' (the "
                       "validation loss) or 'fit score' (search.score: fit)")

    @classmethod
    def from_progress(cls, p: Progress) -> "ProgressPublic":
        return cls.model_validate(dataclasses.asdict(p))  # job_id and status are not repeated here


def valid_text(value: Any) -> Any:
    """``value`` with every lone UTF-16 surrogate in its strings (keys too) replaced by U+FFFD, so
    it always encodes as UTF-8 (specs are checked at submission; older stores may hold some)."""
    if isinstance(value, str):
        return "".join("\ufffd" if "\ud800" <= c <= "\udfff" else c for c in value)
    if isinstance(value, dict):
        return {valid_text(k): valid_text(v) for k, v in value.items()}
    if isinstance(value, list):
        return [valid_text(v) for v in value]
    return value


@dataclasses.dataclass(frozen=True)
class Naming:
    """How a job's states read: its model's positions and, by digit, each position's choices."""

    positions: tuple[str, ...]
    choices: dict[str, tuple[str, ...]]
    names: dict[tuple[str, int], str]  # (position, digit) -> choice name, empty for binary states

    @staticmethod
    def of(spec: dict) -> "Naming":
        return _naming(json.dumps(spec, sort_keys=True))

    def change(self, parent: str, state: str) -> str:
        return describe_change(parent, state, self.positions, self.names)


@functools.lru_cache(maxsize=256)
def _naming(spec_json: str) -> Naming:
    spec = json.loads(spec_json)
    try:  # the spec's own model: its module choices and alternatives
        model = JobSpec.model_validate(spec).model_instance()
    except (ValueError, TypeError):  # a stored spec this version no longer accepts: the plain model
        from neuenh.models import get_model

        model = get_model(spec.get("model", "ggx"))
    return Naming(model.positions, {p: model.choices(p) for p in model.positions}, model.choice_names())


class JobPublic(BaseModel):
    id: str
    name: str | None
    model: str
    status: JobStatus
    terminal: bool
    error: str | None
    reason: str | None = Field(description="why a job that did not fail ended where it did: 'budget' when its "
                                           "budget ran out")
    priority: int
    used_wall_s: float = Field(description="wall time its runs took so far, over restarts")
    used_cpu_s: float = Field(description="CPU time its candidates held so far (wall x CPUs asked)")
    created_at: datetime
    updated_at: datetime
    last_round: int | None = Field(description="index of the last committed round; null before round 0")
    current_state: str | None = Field(description="state of the last committed winner (B_c)")
    spec: dict[str, Any]
    progress: ProgressPublic | None = None
    links: Links
    positions: list[str] = Field(default_factory=list,
                                 description="the model's position names, one per digit of a state string")
    choices: dict[str, list[str]] = Field(default_factory=dict, description=(
        "each position's choices by digit: 0 the original term, then the neural modules (mlpW-W-W), then "
        "alternative analytical terms when the spec offers them (e.g. D: ggx, mlp16-32-16, beckmann, ...)"))

    @classmethod
    def from_record(cls, job: JobRecord, base: str = "/v1", progress: Progress | None = None) -> "JobPublic":
        url = f"{base}/jobs/{job.id}"
        spec = valid_text(job.spec)  # a store written before specs were checked may hold lone surrogates
        model = spec.get("model", "ggx")
        naming = Naming.of(spec)
        return cls(
            id=job.id, name=spec.get("name"), model=model, positions=list(naming.positions),
            choices={p: list(c) for p, c in naming.choices.items()},
            status=job.status,
            terminal=job.terminal, error=job.error, reason=job.reason, priority=int(spec.get("priority", 0)),
            used_wall_s=job.used_wall_s, used_cpu_s=job.used_cpu_s, created_at=_time(job.created_at),
            updated_at=_time(job.updated_at), last_round=job.last_round,
            current_state=job.current_state, spec=spec,
            progress=ProgressPublic.from_progress(progress) if progress and not job.terminal else None,
            links=Links(self=url, history=f"{url}/history", model=f"{url}/model", cancel=f"{url}/cancel"),
        )


class JobList(BaseModel):
    jobs: list[JobPublic]
    next_cursor: str | None = Field(description="pass as ?cursor= for the next page; null on the last")


class CandidatePublic(BaseModel):
    state: str
    change: str = Field(description="what it changed from the round's parent, e.g. '+G' (G made neural), "
                                    "'-G' (analytical again), 'G[1->2]' (another choice), 'stay'")
    ok: bool
    winner: bool
    pruned: bool = Field(description="stopped early by successive halving; its losses are from the cut")
    train_loss: float | None
    val_loss: float | None
    fit_score: float | None = Field(description="held-out log-L1 on the materials the job's data holds out, "
                                                "fitted with the candidate's modules frozen (null: not scored)")
    epochs: int
    wall_s: float
    node: str | None
    error: str | None
    seed: int | None

    @classmethod
    def from_record(cls, c: CandidateRecord, r: RoundRecord, naming: "Naming") -> "CandidatePublic":
        return cls(state=c.state, change=naming.change(r.parent_state, c.state), ok=c.ok,
                   winner=c.state == r.winner_state, pruned=c.pruned, train_loss=c.train_loss,
                   val_loss=c.val_loss, fit_score=c.fit_score, epochs=c.epochs, wall_s=c.wall_s, node=c.node,
                   error=c.error, seed=c.seed)


class WarmupPublic(BaseModel):
    epochs: int
    train_loss: float | None
    val_loss: float | None
    wall_s: float
    node: str | None

    @classmethod
    def from_record(cls, w: WarmupRecord) -> "WarmupPublic":
        return cls.model_validate(dataclasses.asdict(w))


class RoundPublic(BaseModel):
    round: int
    kind: RoundKind = Field(description="'search': every candidate around the parent; 'polish': the final "
                                        "state trained on with a decaying learning rate")
    parent_state: str
    winner_state: str
    change: str = Field(description="what the winner changed from the parent (as a candidate's change)")
    winner_val_loss: float
    winner_fit_score: float | None = Field(description="the winner's fit score (null: not scored)")
    gain_over_start: float | None = Field(description="1 - winner_val_loss / the history's start_val_loss: "
                                                      "the share of the starting state's loss removed so far")
    converged: bool = Field(description="the stay candidate won a search round: the search stopped here")
    outcome: JobStatus | None = Field(description="a polish round: how the search had ended")
    warmup: WarmupPublic | None = Field(description="round 0 of a search that trained its start state first")
    recovered: int = Field(description="candidates that had finished before a restart and were read back, "
                                       "not trained again")
    started_at: datetime
    finished_at: datetime
    wall_s: float
    candidates: list[CandidatePublic]
    extra: dict[str, Any]

    @classmethod
    def from_record(cls, r: RoundRecord, naming: "Naming", start: float | None) -> "RoundPublic":
        return cls(round=r.index, kind=r.kind, parent_state=r.parent_state, winner_state=r.winner_state,
                   change=naming.change(r.parent_state, r.winner_state),
                   winner_val_loss=r.winner_val_loss, winner_fit_score=r.winner_fit_score,
                   gain_over_start=_gain(r.winner_val_loss, start),
                   converged=r.converged, outcome=r.outcome,
                   warmup=WarmupPublic.from_record(r.warmup) if r.warmup else None, recovered=r.recovered,
                   started_at=_time(r.started_at), finished_at=_time(r.finished_at),
                   wall_s=r.finished_at - r.started_at,
                   candidates=[CandidatePublic.from_record(c, r, naming) for c in r.candidates],
                   extra={**r.extra, **({"stop_when": r.stop_reason} if r.stop_reason else {})})  # as before the column


def _score(spec: Any) -> str:
    """A stored spec's search.score ('val' for specs written before it existed or not a mapping)."""
    search = spec.get("search") if isinstance(spec, dict) else None
    return "fit" if isinstance(search, dict) and search.get("score") == "fit" else "val"


class HistoryPublic(BaseModel):
    model_config = ConfigDict(json_schema_extra={"description": "Committed rounds, oldest first."})

    job_id: str
    status: JobStatus
    terminal: bool
    reason: str | None = Field(description="as the job's: 'budget' when its budget ran out")
    current_state: str | None
    score: Literal["val", "fit"] = Field(description="what selected each round's winner (the spec's search.score): "
                                                     "'val' the validation loss, 'fit' the fit score")
    start_val_loss: float | None = Field(description="round 0's stay candidate: the starting state (plain "
                                                     "analytical by default) trained like every candidate")
    gain_over_start: float | None = Field(description="1 - the last winner's val loss / start_val_loss")
    rounds: list[RoundPublic]
    next_since_round: int = Field(description="poll again with ?since_round= this value")

    @classmethod
    def from_records(cls, job: JobRecord, rounds: list[RoundRecord], since_round: int = 0, *,
                     round0: RoundRecord | None = None, last: RoundRecord | None = None) -> "HistoryPublic":
        """``rounds``: the job's committed rounds from ``since_round`` on. ``round0`` (the gain's
        reference) and ``last`` (the job's last committed round) default to ``rounds``' own first
        and last, so a caller passes them only when ``rounds`` does not hold them."""
        naming = Naming.of(valid_text(job.spec))
        round0 = round0 or (rounds[0] if rounds and rounds[0].index == 0 else None)
        last = last or (rounds[-1] if rounds else None)
        start = start_val_loss(round0)
        return cls(job_id=job.id, status=job.status, terminal=job.terminal, reason=job.reason,
                   current_state=job.current_state, score=_score(job.spec),
                   start_val_loss=start, gain_over_start=_gain(last.winner_val_loss, start) if last else None,
                   rounds=[RoundPublic.from_record(r, naming, start) for r in rounds],
                   next_since_round=rounds[-1].index + 1 if rounds else since_round)


class NodePublic(BaseModel):
    id: str
    address: str | None
    alive: bool
    cpus: float
    gpus: float
    memory_bytes: int | None


class SlotHolderPublic(BaseModel):
    job_id: str | None = Field(description="null: another owner's job (a submit token sees its own jobs' ids)")
    candidates: int
    cpus: float
    gpus: float


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
    running_jobs: list[str] = Field(description="the jobs the service is running now (a submit token: its own)")
    other_running_jobs: int = Field(0, description="running jobs of other owners, not named to a submit token")
    max_running_jobs: int = Field(description="how many jobs run at once (NEUENH_MAX_RUNNING_JOBS)")
    holders: list[SlotHolderPublic] = Field(description="per running job, its candidates in flight and what "
                                                        "they hold of the cluster")


class FittedMaterial(BaseModel):
    name: str
    loss: float = Field(description="mean log-L1 of the fitted model on the uploaded measurements")
    samples: int
    params: dict[str, list[float]] = Field(description="fitted analytical parameters by name (physical values)")
    latent: list[float] | None = Field(description="the fitted latent code, or null when the model reads none")
    corrections: dict[str, list] = Field(description="per-material deltas of module weights by weight key "
                                                     "(nested lists of the weight's shape); empty: none")
    capacity: str = Field(description="the fit capacity that produced the parameters (analytical, latent, ...)")
    correction_params: int | None = Field(description="free parameters behind the corrections (null: their size)")
    params_per_material: int = Field(description="free parameters of this material at its capacity")


class DrawPublic(BaseModel):
    """How pairs were drawn from the measured files among a fit's uploads (``neuenh.study.heldout.draw_fit_test``,
    as ``neuenh fit`` draws them)."""

    samples: int = Field(description="pairs drawn from each of them")
    near_mirror: float = Field(description="the share of those pairs with the half vector near the normal")
    seed: int
    materials: list[str] = Field(description="the materials drawn (RGL or MERL uploads); the others were tables")


class FitPublic(BaseModel):
    """Materials fitted with a job's model, its module weights frozen (``POST /v1/jobs/{id}/fit``)."""

    job_id: str
    round: int = Field(description="the committed round whose model was used")
    model: str
    state: str
    protocol: dict = Field(description="the fit protocol and its budget (neuenh.fit)")
    wall_s: float
    materials: list[FittedMaterial]
    drawn: DrawPublic | None = Field(None, description="how pairs were drawn from the uploaded RGL or MERL files; "
                                                       "null when every upload was a table")


class PlanProgressPublic(BaseModel):
    message: str = Field(description="what the planner fits now")
    step: int
    steps: int


class PlanPublic(BaseModel):
    """A scene plan (``neuenh.scene``): per material the cheapest rung of the ladder within tolerance."""

    id: str
    name: str | None
    status: PlanStatus
    terminal: bool
    error: str | None
    created_at: datetime
    updated_at: datetime
    materials_total: int | None = Field(description="the scene's materials, once read")
    materials_done: int = Field(description="materials planned so far (kept across restarts)")
    progress: PlanProgressPublic | None
    scene: dict[str, Any]
    plan: dict[str, Any] | None = Field(description="when DONE: the ladder with measured costs, every material's "
                                                    "choice and results, the frame totals (plan.json)")
    files: dict[str, str] = Field(description="when DONE: file name -> its URL (plan.json, plan.md, "
                                              "cost_vs_error.png, contact_sheet.png, bundles.zip)")

    @classmethod
    def from_record(cls, p: PlanRecord, files: list[str], base: str = "/v1",
                    progress: Any = None, hidden: Path | None = None) -> "PlanPublic":
        """``hidden``: a folder of the service (where uploads are kept) that the answer names by its
        last part only, wherever the scene, the plan or the error mention a path inside it."""
        url = f"{base}/plans/{p.id}/files"
        shown = (lambda v: v) if hidden is None else functools.partial(_hide_folder, prefix=f"{hidden}/",
                                                                       name=f"{hidden.name}/")
        return cls(id=p.id, name=p.scene.get("name"), status=p.status, terminal=p.terminal, error=shown(p.error),
                   created_at=_time(p.created_at), updated_at=_time(p.updated_at), materials_total=p.materials_total,
                   materials_done=p.materials_done,
                   progress=PlanProgressPublic(message=progress.message, step=progress.step, steps=progress.steps)
                   if progress is not None and not p.terminal else None,
                   scene=shown(p.scene), plan=shown(p.result), files={name: f"{url}/{name}" for name in files})


def _hide_folder(value: Any, prefix: str, name: str) -> Any:
    """``value`` with ``prefix`` replaced by ``name`` in every string it holds."""
    if isinstance(value, str):
        return value.replace(prefix, name)
    if isinstance(value, dict):
        return {k: _hide_folder(v, prefix, name) for k, v in value.items()}
    if isinstance(value, list):
        return [_hide_folder(v, prefix, name) for v in value]
    return value


class PlanList(BaseModel):
    plans: list[PlanPublic]


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
    broken_jobs: dict[str, str] = Field(default_factory=dict, description=(
        "jobs the service could not run or update (e.g. a damaged job database), with the reason"))
