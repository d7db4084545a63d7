"""The service's plan queue: scene plans (``orchestrator.plans``) run one at a time, in submission
order, each in a process of its own (``api.plan_worker``), beside the jobs.

* At start it queues every unfinished plan; a plan the service's limits no longer admit (``admit``:
  stored before they applied, or by a more generous configuration) is FAILED saying why instead of
  running again.
* ``cancel(plan_id)`` makes the plan CANCELLED and kills its process if it is the running one (the
  materials it planned stay recorded; its uploads are released).
* A plan whose process ends without ending the plan — killed by the OOM killer, crashed — is FAILED
  saying so; a plan never stays RUNNING to be tried again on every start.
* ``stop()`` ends the running plan's process at once (SIGTERM, then SIGKILL) and leaves the plan
  RUNNING with the materials it planned, so the next start plans only the rest.
* While a plan runs it holds ``cpus`` of the cluster's fair share (``FairShare``, the jobs' own), as a
  job's candidate would: on the service's own machine it trains on the same CPUs.
"""

from __future__ import annotations

import logging
import multiprocessing
import queue
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from neuenh_service.orchestrator.executor import Resources
from neuenh_service.orchestrator.shares import FairShare
from neuenh_service.storage import IllegalTransitionError, PlanRecord, PlanStore

from . import plan_worker
from .settings import Settings

log = logging.getLogger("neuenh.api.plan_queue")

POLL_S = 0.2  # how often the queue's thread looks at the running plan's process
TERMINATE_GRACE_S = 5.0  # a stopping plan's process gets this long to end on SIGTERM before SIGKILL
# What the fork server imports once, so that each plan's process starts without importing torch again
PRELOADED = ["neuenh_service.api.plan_worker", "neuenh_service.api.app", "neuenh_service.orchestrator.plans"]


@dataclass(frozen=True)
class PlanProgress:
    message: str  # what the planner fits now
    step: int  # fits done, of ...
    steps: int


class PlanQueue:
    def __init__(self, plans: PlanStore, settings: Settings, base: Path | None = None, *,
                 share: FairShare | None = None, admit: Callable[[PlanRecord], list[str]] = lambda plan: [],
                 on_ended: Callable[[PlanRecord], None] = lambda plan: None):
        """``settings``: the service's (the plan's process opens the stores from them); ``admit``: what
        is over the service's limits in a plan (nothing: it may run); ``on_ended``: called with each
        plan that ends (DONE, FAILED, CANCELLED)."""
        self.plans, self.settings, self.base = plans, settings, base or Path.cwd()
        self.share, self.admit, self.on_ended = share, admit, on_ended
        self._stopping = threading.Event()
        self._pending: queue.Queue[str | None] = queue.Queue()
        self._progress: dict[str, PlanProgress] = {}
        self._running: tuple[str, multiprocessing.process.BaseProcess] | None = None
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._loop, name="neuenh-plan-queue", daemon=True)
        # Plans fork from a fork server (started at the first plan) that has imported the planner: a
        # process without the service's threads or sockets, so nothing of them leaks into a plan.
        self._context = multiprocessing.get_context("forkserver")
        self._context.set_forkserver_preload(PRELOADED)

    def start(self) -> list[str]:
        resumed = [p.id for p in self.plans.unfinished_plans()]
        for plan_id in resumed:
            self._pending.put(plan_id)
        if resumed:
            log.info("resuming %d unfinished plan(s): %s", len(resumed), ", ".join(resumed))
        self._thread.start()
        return resumed

    def stop(self, timeout: float) -> bool:
        """End the running plan's process and the queue's thread; True when both ended in time."""
        self._stopping.set()
        self._pending.put(None)
        with self._lock:
            running = self._running
        if running is not None:
            _end(running[1], min(TERMINATE_GRACE_S, timeout))
        self._thread.join(timeout)
        return not self._thread.is_alive()

    def enqueue(self, plan_id: str) -> None:
        self._pending.put(plan_id)

    def cancel(self, plan_id: str) -> PlanRecord:
        """CANCELLED, ending its process if it runs (``IllegalTransitionError`` once it has ended)."""
        plan = self.plans.cancel(plan_id)
        with self._lock:
            running = self._running if self._running and self._running[0] == plan_id else None
        if running is not None:
            running[1].kill()  # the queue's thread sees it end and releases the plan's files
        else:
            self.on_ended(plan)  # queued: the queue's thread will skip it
        return plan

    def progress(self, plan_id: str) -> PlanProgress | None:
        return self._progress.get(plan_id)

    def process_id(self, plan_id: str) -> int | None:
        """The pid of the process planning ``plan_id`` now, or None (for operators and tests)."""
        with self._lock:
            return self._running[1].pid if self._running and self._running[0] == plan_id else None

    def _loop(self) -> None:
        while not self._stopping.is_set():
            plan_id = self._pending.get()
            if plan_id is None or self._stopping.is_set():
                break
            try:
                self._run(plan_id)
            except Exception:  # a store that failed under the plan: keep the queue alive for the others
                log.exception("plan %s: the plan queue could not run it", plan_id)
            finally:
                self._progress.pop(plan_id, None)

    def _run(self, plan_id: str) -> None:
        plan = self.plans.get_plan(plan_id)
        if plan.terminal:  # cancelled while it waited
            return
        problems = self.admit(plan)
        if problems:
            self._ended(self.plans.fail(plan_id, "over this service's limits: " + "; ".join(problems)))
            return
        receiver, sender = self._context.Pipe(duplex=False)
        process = self._context.Process(target=plan_worker.run_plan, args=(self.settings, self.base, plan_id, sender),
                                   name=f"neuenh-plan-{plan_id[:8]}", daemon=True)
        holder = f"plan {plan_id}"
        if self.share is not None:
            self.share.limit(holder, Resources(cpus=float(self.settings.plan_cpus), gpus=0.0), 1)
        try:
            with self._lock:
                process.start()
                self._running = (plan_id, process)
            sender.close()  # the child holds the other end: the pipe reads EOF once it has ended
            self._follow(plan_id, process, receiver)
        finally:
            with self._lock:
                self._running = None
            receiver.close()
            if self.share is not None:
                self.share.leave(holder)
        plan = self.plans.get_plan(plan_id)
        if not plan.terminal and not self._stopping.is_set():
            try:
                plan = self.plans.fail(plan_id, f"the planner's process ended without finishing the plan "
                                                f"({_exit_reason(process.exitcode)})")
            except IllegalTransitionError:  # it ended (a cancel) meanwhile
                plan = self.plans.get_plan(plan_id)
        log.info("plan %s: %s", plan_id, plan.status.value)
        if plan.terminal:
            self._ended(plan)

    def _follow(self, plan_id: str, process, receiver) -> None:
        """Record the process's progress messages until it ends."""
        while process.is_alive():
            try:
                if receiver.poll(POLL_S):
                    message, step, steps = receiver.recv()
                    self._progress[plan_id] = PlanProgress(message, step, steps)
            except (EOFError, OSError):  # its end of the pipe closed: the process is ending
                break
        process.join()

    def _ended(self, plan: PlanRecord) -> None:
        try:
            self.on_ended(plan)
        except Exception:
            log.exception("plan %s: releasing its files failed", plan.id)


def _end(process, grace_s: float) -> None:
    """SIGTERM, and SIGKILL if it still runs after ``grace_s`` seconds."""
    process.terminate()
    process.join(grace_s)
    if process.is_alive():
        process.kill()
        process.join(grace_s)


def _exit_reason(code: int | None) -> str:
    if code is not None and code < 0:
        hint = " (killed: out of memory?)" if code == -9 else ""
        return f"killed by signal {-code}{hint}"
    return f"exit code {code}"
