"""The job store: jobs, their committed rounds (with every candidate) and their event log.

This module holds the contract (``JobStore``), the job state machine and the read models. A backend
(``storage.sqlite.SQLiteJobStore`` today) is built by whoever starts the service and handed to the
orchestrator and the API through their constructors.

Conventions shared by every backend:

* **Times** are UTC epoch seconds as ``float`` (``time.time()``), everywhere: records, events,
  round start/finish. Format them at the edge (API, CLI).
* **JSON** (job spec, event payloads, round/candidate ``extra``) must be strict JSON: no NaN or
  infinity, keys are strings. It is checked before anything is written (``InvalidRecordError``).
* **Losses** are finite floats or ``None``: a non-finite loss (a diverged candidate) is stored as
  ``None``, and the candidate's ``error`` says why.
* **Records** are frozen dataclasses; rows never leave the backend.
"""

from __future__ import annotations

import enum
import json
import math
from abc import ABC, abstractmethod
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from .errors import IllegalTransitionError, InvalidRecordError


class JobStatus(enum.StrEnum):
    QUEUED = "QUEUED"
    PREPARING = "PREPARING"
    RUNNING = "RUNNING"
    CONVERGED = "CONVERGED"
    STOPPED = "STOPPED"
    CANCELLED = "CANCELLED"
    FAILED = "FAILED"

    @property
    def terminal(self) -> bool:
        return not TRANSITIONS[self]


_ENDS = {JobStatus.CANCELLED, JobStatus.FAILED}

#: The job state machine: status -> statuses it may move to. Terminal statuses map to nothing.
TRANSITIONS: Mapping[JobStatus, frozenset[JobStatus]] = {
    JobStatus.QUEUED: frozenset({JobStatus.PREPARING, *_ENDS}),
    JobStatus.PREPARING: frozenset({JobStatus.RUNNING, *_ENDS}),
    JobStatus.RUNNING: frozenset({JobStatus.CONVERGED, JobStatus.STOPPED, *_ENDS}),
    JobStatus.CONVERGED: frozenset(),
    JobStatus.STOPPED: frozenset(),
    JobStatus.CANCELLED: frozenset(),
    JobStatus.FAILED: frozenset(),
}

UNFINISHED: frozenset[JobStatus] = frozenset(s for s in JobStatus if not s.terminal)

class EventKind(enum.StrEnum):
    """What an event of a job's log says. The store writes the first three itself; the orchestrator
    appends the others (``append_event`` also takes any other non-empty name, read back as a str)."""

    STATUS = "status"        # {"status", "previous", "error"[, "reason"]}; also written on creation
    ROUND = "round"          # ``round_payload``: a round committed
    CANDIDATE = "candidate"  # ``candidate_payload``: a finished candidate recorded
    PREPARING = "preparing"  # {}: a preparation of the dataset started
    PREPARATION_INTERRUPTED = "preparation_interrupted"  # {}: it stopped cleanly (cancel, shutdown)
    DATASET = "dataset"      # {"key", "materials", "train", "val", "bytes"}: it finished
    ROUND_STARTED = "round_started"  # {"round", "state", "candidates"}
    COST = "cost"            # {"state", "ns"}: a state's evaluation cost measured (search.cost "time")
    BUDGET_SPENT = "budget_spent"  # {"detail"}: what of the budget ran out


_EVENT_KINDS = frozenset(k.value for k in EventKind)


def check_transition(job_id: str, old: JobStatus, new: JobStatus) -> None:
    """Raise ``IllegalTransitionError`` unless ``old -> new`` is an edge of ``TRANSITIONS``."""
    if new not in TRANSITIONS[old]:
        allowed = ", ".join(sorted(s.value for s in TRANSITIONS[old])) or "nothing (terminal)"
        raise IllegalTransitionError(
            f"job {job_id}: cannot move from {old.value} to {new.value}; "
            f"{old.value} may move to {allowed}")


def stored_idempotency_key(key: str, owner: str | None) -> str:
    """An idempotency key as stored: scoped by its owner, so two owners' equal keys name two jobs (or
    plans) and neither learns of the other's. A key holds no line break (an HTTP header cannot), so
    owner and key never run together."""
    if not isinstance(key, str) or not key or "\n" in key or "\r" in key:
        raise InvalidRecordError(f"an idempotency key is a non-empty string without line breaks, got {key!r}")
    return key if owner is None else f"{owner}\n{key}"


def caller_idempotency_key(stored: str | None) -> str | None:
    """The key as its caller gave it (``stored_idempotency_key`` undone)."""
    return None if stored is None else stored.rsplit("\n", 1)[-1]


def canonical_json(value: Any, what: str) -> str:
    """Strict, canonical JSON text (sorted keys): equal values give equal text."""
    try:
        return json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise InvalidRecordError(f"{what} is not strict JSON: {exc}") from None


def _json_roundtrip(value: Any, what: str) -> Any:
    return json.loads(canonical_json(value, what))


def _finite_or_none(x: float | None) -> float | None:
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


# --------------------------------------------------------------------------------- read models


@dataclass(frozen=True)
class JobRecord:
    id: str
    spec: dict[str, Any]
    status: JobStatus
    created_at: float
    updated_at: float
    error: str | None = None
    idempotency_key: str | None = None
    last_round: int | None = None      # index of the last committed round; None before round 0
    current_state: str | None = None   # B_c: winner of ``last_round``; None before round 0
    owner: str | None = None           # the name of the token that submitted it (None: no named tokens)
    reason: str | None = None          # why a job that did not fail ended where it did, e.g. "budget"
    used_wall_s: float = 0.0           # wall time its runs took so far, summed over restarts
    used_cpu_s: float = 0.0            # CPU time its candidates held (wall x CPUs asked), over restarts
    unfinished_preparations: int = 0   # dataset preparations begun since the last one that ended

    @property
    def terminal(self) -> bool:
        return self.status.terminal

    @property
    def next_round(self) -> int:
        """Index of the round to run (and commit) next."""
        return 0 if self.last_round is None else self.last_round + 1


@dataclass(frozen=True)
class StoreStatistics:
    """What ``/metrics`` reports from the store: durable across restarts, so counters never reset."""

    jobs_by_status: dict[JobStatus, int]
    candidates: int             # committed candidates, all jobs
    failed_candidates: int      # of which training failed (diverged, crashed)
    candidate_seconds: tuple[float, ...]  # each committed candidate's training wall time
    round_seconds: tuple[float, ...]      # each committed round's wall time


@dataclass(frozen=True)
class JobPage:
    jobs: tuple[JobRecord, ...]
    next_cursor: str | None  # pass to ``list_jobs(cursor=...)``; None on the last page


class RoundKind(enum.StrEnum):
    SEARCH = "search"  # a round of the hypercube search: every candidate around the parent
    POLISH = "polish"  # the final state trained on (``search.polish_epochs``): one candidate


@dataclass(frozen=True)
class WarmupRecord:
    """The starting state's training before round 0 (``search.warmup_epochs``), recorded on round 0."""

    epochs: int
    train_loss: float | None
    val_loss: float | None
    wall_s: float
    node: str | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "epochs", int(self.epochs))
        object.__setattr__(self, "train_loss", _finite_or_none(self.train_loss))
        object.__setattr__(self, "val_loss", _finite_or_none(self.val_loss))
        object.__setattr__(self, "wall_s", float(self.wall_s))


@dataclass(frozen=True)
class HalvingRecord:
    """Successive halving within a round (``search.prune: halving``): every candidate trained
    ``first_epochs``, the better half went on; ``early_val_loss`` is each one's loss at the cut."""

    first_epochs: int
    early_val_loss: dict[str, float | None]

    def __post_init__(self) -> None:
        object.__setattr__(self, "first_epochs", int(self.first_epochs))
        object.__setattr__(self, "early_val_loss",
                           {str(k): _finite_or_none(v) for k, v in dict(self.early_val_loss).items()})


@dataclass(frozen=True)
class CandidateRecord:
    """One trained candidate of a round. Input of ``commit_round`` and part of its read model."""

    state: str
    train_loss: float | None
    val_loss: float | None
    epochs: int
    wall_s: float
    node: str | None = None     # where it trained (Ray node id / hostname)
    error: str | None = None    # set when the candidate failed (non-finite loss, exception, pruned)
    seed: int | None = None     # seed of its fresh modules: an interrupted round re-runs with it
    pruned: bool = False        # stopped early by successive halving (its losses are from the cut)
    extra: dict[str, Any] = field(default_factory=dict)  # free-form, e.g. epoch_losses
    fit_score: float | None = None  # on the materials the data held out (neuenh.selection); None: not scored

    def __post_init__(self) -> None:
        if not isinstance(self.state, str) or not self.state:
            raise InvalidRecordError(f"candidate state must be a non-empty string, got {self.state!r}")
        object.__setattr__(self, "train_loss", _finite_or_none(self.train_loss))
        object.__setattr__(self, "val_loss", _finite_or_none(self.val_loss))
        object.__setattr__(self, "fit_score", _finite_or_none(self.fit_score))
        object.__setattr__(self, "epochs", int(self.epochs))
        object.__setattr__(self, "wall_s", float(self.wall_s))
        object.__setattr__(self, "pruned", bool(self.pruned))
        object.__setattr__(self, "extra", _json_roundtrip(dict(self.extra), f"candidate {self.state} extra"))

    @property
    def ok(self) -> bool:
        return self.error is None and self.val_loss is not None


@dataclass(frozen=True)
class RoundRecord:
    """One committed round: the parent state, every candidate and the winner (whose checkpoint is
    stored under ``artifact_key`` in the ArtifactStore). ``winner_state`` must be one of the
    candidates' states and that candidate must have a finite ``val_loss``."""

    index: int
    parent_state: str
    winner_state: str
    candidates: tuple[CandidateRecord, ...]
    started_at: float
    finished_at: float
    artifact_key: str | None = None
    kind: RoundKind = RoundKind.SEARCH
    outcome: JobStatus | None = None      # a polish round: how the search ended (CONVERGED or STOPPED)
    warmup: WarmupRecord | None = None    # round 0 of a search that warmed up first
    halving: HalvingRecord | None = None  # a round pruned by successive halving
    recovered: int = 0                    # candidates trained before a restart and read back, not re-run
    stop_reason: str | None = None        # why search.stop_when ended the search after this round
    extra: dict[str, Any] = field(default_factory=dict)  # free-form

    def __post_init__(self) -> None:
        object.__setattr__(self, "index", int(self.index))
        object.__setattr__(self, "recovered", int(self.recovered))
        object.__setattr__(self, "candidates", tuple(self.candidates))
        object.__setattr__(self, "started_at", float(self.started_at))
        object.__setattr__(self, "finished_at", float(self.finished_at))
        object.__setattr__(self, "kind", RoundKind(self.kind))
        if self.outcome is not None:
            object.__setattr__(self, "outcome", JobStatus(self.outcome))
        object.__setattr__(self, "extra", _json_roundtrip(dict(self.extra), f"round {self.index} extra"))
        if self.index < 0:
            raise InvalidRecordError(f"round index must be >= 0, got {self.index}")
        if (self.kind is RoundKind.POLISH) != (self.outcome is not None):
            raise InvalidRecordError(f"round {self.index}: a polish round, and only a polish round, records "
                                     f"the search's outcome")
        if self.stop_reason is not None and (self.kind is not RoundKind.SEARCH or not isinstance(
                self.stop_reason, str) or not self.stop_reason):
            raise InvalidRecordError(f"round {self.index}: a stop reason is a non-empty string on a search round, "
                                     f"got {self.stop_reason!r} on a {self.kind.value} round")
        if not self.candidates:
            raise InvalidRecordError(f"round {self.index} has no candidates")
        winner = self.winner  # raises if absent
        if winner.val_loss is None:
            raise InvalidRecordError(
                f"round {self.index}: winner {self.winner_state} has no finite validation loss")

    @property
    def winner(self) -> CandidateRecord:
        for c in self.candidates:
            if c.state == self.winner_state:
                return c
        raise InvalidRecordError(
            f"round {self.index}: winner {self.winner_state} is not one of its candidates")

    @property
    def winner_val_loss(self) -> float:
        return self.winner.val_loss  # type: ignore[return-value]  # checked finite on creation

    @property
    def winner_fit_score(self) -> float | None:
        return self.winner.fit_score

    @property
    def converged(self) -> bool:
        """The stay candidate won a search round: the search stopped here."""
        return self.kind is RoundKind.SEARCH and self.winner_state == self.parent_state


@dataclass(frozen=True)
class FinishedCandidate:
    """A candidate whose training finished, persisted as it arrived, before its round commits: a
    restart re-runs only the candidates of the interrupted round that have none. ``phase`` tells a
    round's trainings apart ("train", "warmup", "halving", "continue", "polish"); the trained bundle
    is in the ArtifactStore under ``artifact_key`` (content-addressed; None when training failed)."""

    round_index: int
    phase: str
    candidate: CandidateRecord
    artifact_key: str | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "round_index", int(self.round_index))
        if self.round_index < 0:
            raise InvalidRecordError(f"round index must be >= 0, got {self.round_index}")
        if not isinstance(self.phase, str) or not self.phase:
            raise InvalidRecordError(f"a candidate's phase must be a non-empty string, got {self.phase!r}")
        if not isinstance(self.candidate, CandidateRecord):
            raise InvalidRecordError(f"candidate must be a CandidateRecord, got {type(self.candidate).__name__}")
        if (self.artifact_key is None) == self.candidate.ok:
            raise InvalidRecordError(f"candidate {self.candidate.state}: a trained bundle is stored exactly "
                                     "when training succeeded")


def start_val_loss(round0: RoundRecord | None) -> float | None:
    """Round 0's stay candidate's validation loss: the starting state (plain analytical unless the
    spec says otherwise) trained like every candidate, what a search's gain is measured against.
    None before round 0 or when that candidate failed."""
    if round0 is None:
        return None
    stay = next((c for c in round0.candidates if c.state == round0.parent_state and c.ok), None)
    return stay.val_loss if stay is not None and stay.val_loss > 0 else None


def trained_epochs(rounds: list[RoundRecord]) -> int:
    """Epochs the last committed winner has trained in all: the warm-up, then every round's winner."""
    warmup = rounds[0].warmup.epochs if rounds and rounds[0].warmup else 0
    return warmup + sum(r.winner.epochs for r in rounds)


@dataclass(frozen=True)
class EventRecord:
    job_id: str
    seq: int      # 1, 2, 3, ... per job, without gaps
    time: float
    kind: EventKind | str  # an EventKind, or another name a caller appended
    payload: dict[str, Any]

    def __post_init__(self) -> None:
        if self.kind in _EVENT_KINDS:
            object.__setattr__(self, "kind", EventKind(self.kind))


# ------------------------------------------------------------------------------------ contract


class JobStore(ABC):
    """Durable record of search jobs. Every backend honours this contract (and
    ``tests/storage/test_job_store.py`` checks it against each one):

    * **Jobs.** ``create_job`` stores a spec as ``QUEUED`` under a fresh id. With an
      ``idempotency_key`` that the same owner already used, it returns that job (``created=False``)
      if the spec is equal, and raises ``ConflictError`` if it differs; keys are per owner (another
      owner's equal key is another job). ``get_job`` raises
      ``NotFoundError`` for an unknown id (every method taking a ``job_id`` does).
    * **Status** follows ``TRANSITIONS`` (QUEUED -> PREPARING -> RUNNING -> CONVERGED | STOPPED |
      CANCELLED | FAILED, and QUEUED/PREPARING -> CANCELLED | FAILED). ``set_status`` checks the
      edge and writes atomically, so of two racing changes (cancel vs. converge) exactly one wins
      and the other gets ``IllegalTransitionError``. An ``error`` reason is only accepted with a
      terminal status. Every change (and the creation) appends a ``STATUS`` event.
    * **Rounds.** ``commit_round`` writes the round, all its candidates, the job's
      ``last_round``/``current_state`` and a ``ROUND`` event in ONE transaction: a reader sees a
      round complete or not at all. Rounds are committed in order (index = ``job.next_round``) and
      only while the job is RUNNING. Re-committing a stored index is idempotent by content: the
      identical record returns the stored one and writes nothing; a different one raises
      ``ConflictError``. Committed rounds never change.
    * **Finished candidates** (``record_candidate``) are kept per job, round, phase and state as
      they arrive, before their round commits. Recording one stores it, charges the usage it cost
      and appends a ``CANDIDATE`` event in ONE transaction: all three or none. Recording the same
      one again is idempotent by content (it writes nothing: no second charge, no second event); a
      different one raises ``ConflictError``. ``finished_candidates`` reads a round's.
    * **Preparations.** ``begin_preparation`` counts a start of the job's dataset preparation in
      ``unfinished_preparations`` and appends a ``PREPARING`` event; ``end_preparation`` sets the
      count to 0 and appends how it ended (``DATASET`` or ``PREPARATION_INTERRUPTED``); each in one
      transaction.
    * **State costs** (``record_state_cost``): one measured evaluation cost per job and state
      (``search.cost: time``). The first recorded stays: recording a state again returns the stored
      cost and writes nothing. Recording one stores it and appends a ``COST`` event in ONE
      transaction. ``state_costs`` reads a job's, state -> nanoseconds.
    * **Usage** (``charge``) adds wall and CPU seconds to the job's totals in one write, so what a
      budget counts survives restarts; totals only grow.
    * **Events** are numbered 1, 2, 3, ... per job without gaps, in commit order, also when
      appended from many threads.
    * **Threads and processes.** One store object may be used from many threads at once; several
      processes may open the same store (one writer at a time, readers never blocked for long).
    """

    @abstractmethod
    def create_job(self, spec: Mapping[str, Any], *,
                   idempotency_key: str | None = None, owner: str | None = None) -> tuple[JobRecord, bool]:
        """Store a new QUEUED job owned by ``owner``; returns ``(job, created)``. ``created`` is
        False when an existing job was returned for a repeated ``idempotency_key``."""

    @abstractmethod
    def get_job(self, job_id: str) -> JobRecord:
        """The job, or ``NotFoundError``."""

    @abstractmethod
    def list_jobs(self, *, status: JobStatus | Iterable[JobStatus] | None = None,
                  limit: int = 50, cursor: str | None = None, owner: str | None = None) -> JobPage:
        """Jobs newest first, optionally only those with the given status(es) and ``owner``.
        ``cursor`` is the ``next_cursor`` of the previous page (opaque); pages are stable while
        jobs are added."""

    @abstractmethod
    def statistics(self) -> StoreStatistics:
        """Counts and durations over every job (``StoreStatistics``)."""

    @abstractmethod
    def unfinished_jobs(self) -> list[JobRecord]:
        """Every job that is not terminal, oldest first: what to resume after a restart."""

    @abstractmethod
    def set_status(self, job_id: str, status: JobStatus, *, error: str | None = None,
                   reason: str | None = None) -> JobRecord:
        """Move the job to ``status`` (see the state machine); returns the updated job. ``error``
        (why it failed) and ``reason`` (why it ended where it did, e.g. "budget") are only
        recorded with a terminal status."""

    @abstractmethod
    def record_candidate(self, job_id: str, finished: FinishedCandidate, *, wall_s: float = 0.0,
                         cpu_s: float = 0.0) -> JobRecord:
        """Persist one finished candidate of the job's next round, charge ``wall_s`` and ``cpu_s``
        (as ``charge``) and append its ``CANDIDATE`` event, atomically (see the class docstring);
        returns the job with its usage."""

    @abstractmethod
    def finished_candidates(self, job_id: str, round_index: int) -> list[FinishedCandidate]:
        """The finished candidates recorded for ``round_index``, in the order they were recorded."""

    @abstractmethod
    def begin_preparation(self, job_id: str) -> JobRecord:
        """Count a start of the job's dataset preparation and log it (see the class docstring)."""

    @abstractmethod
    def end_preparation(self, job_id: str, kind: EventKind, payload: Mapping[str, Any] | None = None) -> JobRecord:
        """The preparation ended as ``kind`` says (``DATASET`` or ``PREPARATION_INTERRUPTED``)."""

    @abstractmethod
    def record_state_cost(self, job_id: str, state: str, ns: float) -> float:
        """Keep ``ns`` as ``state``'s cost unless one is kept already; returns the kept one."""

    @abstractmethod
    def state_costs(self, job_id: str) -> dict[str, float]:
        """The job's kept costs: state -> nanoseconds per evaluation."""

    @abstractmethod
    def charge(self, job_id: str, *, wall_s: float = 0.0, cpu_s: float = 0.0) -> JobRecord:
        """Add non-negative seconds to the job's ``used_wall_s`` and ``used_cpu_s``; returns the job."""

    @abstractmethod
    def commit_round(self, job_id: str, record: RoundRecord) -> RoundRecord:
        """Atomically store a complete round (see the class docstring); returns it as stored."""

    @abstractmethod
    def rounds(self, job_id: str, *, since_round: int = 0, until_round: int | None = None) -> list[RoundRecord]:
        """Committed rounds with ``since_round <= index <= until_round`` (no upper bound when None),
        in order, each with its candidates in the order they were committed."""

    @abstractmethod
    def last_round(self, job_id: str) -> RoundRecord | None:
        """The last committed round, or None before the first commit."""

    @abstractmethod
    def append_event(self, job_id: str, kind: EventKind | str,
                     payload: Mapping[str, Any] | None = None) -> EventRecord:
        """Append an event to the job's log; returns it with its ``seq`` and ``time``."""

    @abstractmethod
    def events(self, job_id: str, *, after_seq: int = 0, limit: int | None = None) -> list[EventRecord]:
        """Events with ``seq > after_seq``, in order (at most ``limit``)."""

    def close(self) -> None:
        """Release connections. The store must not be used afterwards."""

    def __enter__(self) -> "JobStore":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def status_filter(status: JobStatus | Iterable[JobStatus] | None) -> list[JobStatus] | None:
    """Normalise ``list_jobs``'s ``status`` argument (one status, several, or None)."""
    if status is None:
        return None
    if isinstance(status, (str, JobStatus)):
        return [JobStatus(status)]
    return [JobStatus(s) for s in status]


def validate_error(job_id: str, status: JobStatus, error: str | None, reason: str | None = None) -> None:
    if (error is not None or reason is not None) and not status.terminal:
        raise InvalidRecordError(
            f"job {job_id}: an error or reason is only recorded with a terminal status, not {status.value}")


def validate_preparation_end(job_id: str, kind: EventKind | str) -> EventKind:
    if kind not in (EventKind.DATASET, EventKind.PREPARATION_INTERRUPTED):
        raise InvalidRecordError(f"job {job_id}: a preparation ends as {EventKind.DATASET.value} or "
                                 f"{EventKind.PREPARATION_INTERRUPTED.value}, not {kind!r}")
    return EventKind(kind)


def validate_state_cost(job_id: str, state: str, ns: float) -> float:
    if not isinstance(state, str) or not state.isdigit():
        raise InvalidRecordError(f"job {job_id}: a state is a string of digits, got {state!r}")
    if isinstance(ns, bool) or not isinstance(ns, (int, float)) or not math.isfinite(ns) or ns <= 0:
        raise InvalidRecordError(f"job {job_id}: state {state}'s cost must be a positive number of "
                                 f"nanoseconds, got {ns!r}")
    return float(ns)


def validate_charge(job_id: str, wall_s: float, cpu_s: float) -> tuple[float, float]:
    wall_s, cpu_s = float(wall_s), float(cpu_s)
    if not (math.isfinite(wall_s) and math.isfinite(cpu_s) and wall_s >= 0 and cpu_s >= 0):
        raise InvalidRecordError(f"job {job_id}: usage is charged in finite, non-negative seconds, "
                                 f"got wall {wall_s!r}, cpu {cpu_s!r}")
    return wall_s, cpu_s


def candidate_payload(finished: FinishedCandidate) -> dict[str, Any]:
    """The ``CANDIDATE`` event of a finished candidate: where it belongs and how it trained."""
    c = finished.candidate
    return {"round": finished.round_index, "phase": finished.phase, "state": c.state, "seed": c.seed,
            "train_loss": c.train_loss, "val_loss": c.val_loss, "fit_score": c.fit_score, "epochs": c.epochs,
            "wall_s": c.wall_s, "node": c.node, "error": c.error}


def round_payload(record: RoundRecord) -> dict[str, Any]:
    return {"round": record.index, "winner_state": record.winner_state,
            "winner_val_loss": record.winner_val_loss, "winner_fit_score": record.winner_fit_score,
            "artifact_key": record.artifact_key}


__all__ = [
    "JobStatus", "TRANSITIONS", "UNFINISHED", "EventKind", "JobRecord", "JobPage",
    "CandidateRecord", "FinishedCandidate", "RoundRecord", "RoundKind", "WarmupRecord", "HalvingRecord",
    "EventRecord", "JobStore",
    "check_transition", "trained_epochs",
]
