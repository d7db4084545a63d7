"""The service's plan queue: scene plans (``orchestrator.plans``) run one at a time on a thread of
their own, in submission order, beside the jobs. At start it queues every unfinished plan; ``stop()``
asks the running plan to halt between two fits, leaving it RUNNING with the materials it planned, so
the next start plans only the rest."""

from __future__ import annotations

import logging
import queue
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from neuenh_service.orchestrator.plans import PlanRunner
from neuenh_service.storage import ArtifactStore, PlanRecord, PlanStore

log = logging.getLogger("neuenh.api.plan_queue")


@dataclass(frozen=True)
class PlanProgress:
    message: str  # what the planner fits now
    step: int  # fits done, of ...
    steps: int


class PlanQueue:
    def __init__(self, plans: PlanStore, artifacts: ArtifactStore, base: Path | None = None,
                 on_ended: Callable[[PlanRecord], None] = lambda plan: None):
        """``on_ended``: called with each plan that ends here (DONE or FAILED)."""
        self.plans, self.on_ended = plans, on_ended
        self._stopping = threading.Event()
        self._pending: queue.Queue[str | None] = queue.Queue()
        self._progress: dict[str, PlanProgress] = {}
        self.runner = PlanRunner(plans, artifacts, base=base, should_stop=self._stopping.is_set,
                                 on_progress=self._record)
        self._thread = threading.Thread(target=self._loop, name="neuenh-plan-runner", daemon=True)

    def start(self) -> list[str]:
        resumed = [p.id for p in self.plans.unfinished_plans()]
        for plan_id in resumed:
            self._pending.put(plan_id)
        if resumed:
            log.info("resuming %d unfinished plan(s): %s", len(resumed), ", ".join(resumed))
        self._thread.start()
        return resumed

    def stop(self, timeout: float) -> bool:
        self._stopping.set()
        self._pending.put(None)
        self._thread.join(timeout)
        return not self._thread.is_alive()

    def enqueue(self, plan_id: str) -> None:
        self._pending.put(plan_id)

    def progress(self, plan_id: str) -> PlanProgress | None:
        return self._progress.get(plan_id)

    def _record(self, plan_id: str, message: str, step: int, steps: int) -> None:
        self._progress[plan_id] = PlanProgress(message, step, steps)

    def _loop(self) -> None:
        while not self._stopping.is_set():
            plan_id = self._pending.get()
            if plan_id is None or self._stopping.is_set():
                break
            try:
                plan = self.runner.run(plan_id)
                log.info("plan %s: %s", plan_id, plan.status.value)
                if plan.terminal:
                    self.on_ended(plan)
            except Exception:  # the runner records a plan's failure itself; keep the thread alive
                log.exception("plan %s: the plan queue could not run it", plan_id)
            finally:
                self._progress.pop(plan_id, None)
