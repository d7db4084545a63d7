"""The plan store: scene plans the service runs (``neuenh.scene``), and each material's result as it
is planned, so a restart keeps every material already planned and plans only the rest.

The contract (``PlanStore``), its records and its state machine; the backend
(``storage.sqlite.SQLitePlanStore``, on the job store's SQLite file) is built by whoever starts the
service and handed in. Conventions are the job store's (``storage.jobs``): UTC epoch seconds,
strict JSON checked before anything is written, frozen records.

* **Atomicity.** ``record_material`` writes one material's result in one transaction; ``finish``
  writes the whole plan and the DONE status in one transaction.
* **Idempotency.** Recording a material twice keeps the first result (a resumed plan that re-plans
  a material it had finished does not change it); ``create_plan`` with an idempotency key the same
  owner already used for the same scene returns that plan (keys are per owner).
* **Status.** QUEUED -> RUNNING -> DONE | FAILED, and QUEUED/RUNNING -> CANCELLED | FAILED; of two
  racing changes (a cancel and a finish) one wins, the other gets ``IllegalTransitionError``.
* **Threads.** Every method may be called from any thread.
"""

from __future__ import annotations

import enum
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from .errors import IllegalTransitionError


class PlanStatus(enum.StrEnum):
    QUEUED = "QUEUED"
    RUNNING = "RUNNING"
    DONE = "DONE"
    FAILED = "FAILED"
    CANCELLED = "CANCELLED"

    @property
    def terminal(self) -> bool:
        return self in (PlanStatus.DONE, PlanStatus.FAILED, PlanStatus.CANCELLED)


PLAN_TRANSITIONS: Mapping[PlanStatus, frozenset[PlanStatus]] = {
    PlanStatus.QUEUED: frozenset({PlanStatus.RUNNING, PlanStatus.FAILED, PlanStatus.CANCELLED}),
    PlanStatus.RUNNING: frozenset({PlanStatus.DONE, PlanStatus.FAILED, PlanStatus.CANCELLED}),
    PlanStatus.DONE: frozenset(),
    PlanStatus.FAILED: frozenset(),
    PlanStatus.CANCELLED: frozenset(),
}


def check_plan_transition(plan_id: str, old: PlanStatus, new: PlanStatus) -> None:
    if new != old and new not in PLAN_TRANSITIONS[old]:
        raise IllegalTransitionError(f"plan {plan_id}: {old} -> {new} is not allowed")


@dataclass(frozen=True)
class PlanRecord:
    id: str
    scene: dict[str, Any]
    status: PlanStatus
    created_at: float
    updated_at: float
    owner: str | None = None
    error: str | None = None
    materials_total: int | None = None  # known once the scene's materials are read
    materials_done: int = 0
    result: dict[str, Any] | None = field(default=None, repr=False)  # the plan (Plan.to_json), when DONE
    files: dict[str, str] = field(default_factory=dict)  # when DONE: each stored file's SHA-256 by name

    @property
    def terminal(self) -> bool:
        return self.status.terminal


class PlanStore(ABC):
    """Durable scene plans (module doc for atomicity, idempotency and threads)."""

    @abstractmethod
    def create_plan(self, scene: Mapping[str, Any], *, owner: str | None = None,
                    idempotency_key: str | None = None) -> tuple[PlanRecord, bool]:
        """A new QUEUED plan (and True), or the plan this key created for the same scene (and False);
        the key with another scene is a ``ConflictError``."""

    @abstractmethod
    def get_plan(self, plan_id: str) -> PlanRecord:
        """``NotFoundError`` for an unknown id."""

    @abstractmethod
    def list_plans(self, *, owner: str | None = None, limit: int = 100) -> list[PlanRecord]:
        """Newest first; only ``owner``'s when given."""

    @abstractmethod
    def unfinished_plans(self) -> list[PlanRecord]:
        """QUEUED and RUNNING plans, oldest first: what a restarted service runs again."""

    @abstractmethod
    def start(self, plan_id: str, materials_total: int) -> PlanRecord:
        """RUNNING, knowing how many materials the scene has (again after a restart: idempotent)."""

    @abstractmethod
    def record_material(self, plan_id: str, name: str, result: Mapping[str, Any]) -> None:
        """One material's result (``MaterialPlan.to_json``); the first one recorded stays."""

    @abstractmethod
    def planned_materials(self, plan_id: str) -> dict[str, dict[str, Any]]:
        """Name -> result of every material recorded so far, in recording order."""

    @abstractmethod
    def finish(self, plan_id: str, result: Mapping[str, Any], files: Mapping[str, str] | None = None) -> PlanRecord:
        """DONE with the whole plan and the SHA-256 of each of its stored files (by name), so a file
        read back can be checked."""

    @abstractmethod
    def fail(self, plan_id: str, error: str) -> PlanRecord:
        """FAILED, saying why."""

    @abstractmethod
    def cancel(self, plan_id: str) -> PlanRecord:
        """CANCELLED (from QUEUED or RUNNING; ``IllegalTransitionError`` once it has ended)."""
