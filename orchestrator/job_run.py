"""One job's run: what every step of a running job needs, owned by one object.

A ``JobRun`` is built by ``Orchestrator.run`` for one job and lives while the job runs. It holds the
job id and its parsed spec, the model graph and the search constraints, the resources and training
config every candidate gets, the dataset handle once prepared, the stores and the executor, and the
clock progress reports count from. Its steps (prepare, warm up, a search round, the polish, the
commit) follow the state machine of ``orchestrator.runner``.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from typing import Callable

from neuenh.search import Outcome, candidate_seed, hamming_ball, initial_state, keep_better_half, select
from neuenh_service.storage import (ArtifactStore, CandidateRecord, EventKind, FinishedCandidate, HalvingRecord, JobRecord, JobStatus, JobStore, RoundKind,
                     RoundRecord, WarmupRecord)

from .dataset import prepare_dataset
from .executor import CandidateReport, CandidateTask, Executor, Resources, TrainRequest, unlimited
from .policies import cost_policy, round_pruning, selection_score
from .progress import Progress
from .shares import FairShare
from .spec import JobSpec

log = logging.getLogger("neuenh.orchestrator")

QUEUED, PREPARING, RUNNING = JobStatus.QUEUED, JobStatus.PREPARING, JobStatus.RUNNING
MAX_PREPARE_ATTEMPTS = 2  # unfinished preparations before a job fails instead of retrying
CONVERGED, STOPPED, CANCELLED = JobStatus.CONVERGED, JobStatus.STOPPED, JobStatus.CANCELLED

PRUNED = "pruned by successive halving"


@dataclasses.dataclass(frozen=True)
class RoundResult:
    """A trained round before its commit: the winner, every report in ball order, with successive
    halving its record and the states it pruned; and what the round record says besides (its kind,
    a polish round's outcome, round 0's warm-up, why ``stop_when`` ended the search after it)."""

    winner: CandidateReport
    reports: list[CandidateReport]
    halving: HalvingRecord | None = None
    pruned: frozenset[str] = frozenset()
    kind: RoundKind = RoundKind.SEARCH
    outcome: JobStatus | None = None
    warmup: WarmupRecord | None = None
    stop_reason: str | None = None


class Cancelled(Exception):
    """The job was cancelled (its status is CANCELLED in the store)."""


class Interrupted(Exception):
    """This process is stopping: the job is left as it is and resumes on the next start."""


class BudgetSpent(Exception):
    """The job's budget ran out: it stops at its last committed round (STOPPED, reason "budget")."""


class JobRun:
    def __init__(self, job_id: str, spec: JobSpec, jobs: JobStore, artifacts: ArtifactStore, executor: Executor,
                 on_progress: Callable[[Progress], None], should_stop: Callable[[], bool],
                 resource_wait_s: float = 600.0, share: FairShare | None = None):
        self.job_id, self.spec = job_id, spec
        self.share = share
        self.resource_wait_s = resource_wait_s
        self.jobs, self.artifacts, self.executor = jobs, artifacts, executor
        self.on_progress, self.should_stop = on_progress, should_stop
        self.graph = spec.model_instance().graph
        self.digit_counts = spec.model_instance().digit_counts
        self.digits = spec.digits()
        self.constraints = spec.constraints()
        self.resources = Resources(spec.resources.cpus_per_candidate, spec.resources.gpus_per_candidate)
        self.train_config = spec.train_config()
        self.clock = time.perf_counter()  # progress reports count from here
        self.names: list[str] = []  # the dataset's materials, once prepared
        self.dataset: object | None = None  # the executor's handle, once prepared
        self.recovered: dict[int, int] = {}  # round -> candidates read back instead of trained
        self.pruning = round_pruning(spec)  # search.prune
        self.score = selection_score(spec)  # search.score
        self.costs = cost_policy(spec, jobs, job_id)  # search.cost
        self.stop_reason: str | None = None  # why search.stop_when ended the search
        job = jobs.get_job(job_id)
        self.used_wall_s, self.used_cpu_s = job.used_wall_s, job.used_cpu_s  # as stored, over restarts
        self.charged_at = time.monotonic()  # wall time since then is not yet charged
        self.enforce_budget = False  # from RUNNING on (a STOPPED job must have been RUNNING)

    # -- the state machine ---------------------------------------------------------------------
    def execute(self) -> None:
        """From the job's stored status and last committed round to a terminal status."""
        if self.jobs.get_job(self.job_id).status == QUEUED:
            self.jobs.set_status(self.job_id, PREPARING)
        self.check_cancel()
        self.prepare()
        self.wait_for_resources()
        if self.jobs.get_job(self.job_id).status == PREPARING:
            self.jobs.set_status(self.job_id, RUNNING)
        self.enforce_budget = True
        self.check_cancel()
        last = self.jobs.last_round(self.job_id)
        if last is not None and last.kind is RoundKind.POLISH:  # crashed after the polish commit
            self.jobs.set_status(self.job_id, last.outcome)
            return
        warmup = None
        if last is None:
            k, state = 0, initial_state(len(self.graph), self.digits, self.constraints)
            parent = self.spec.initial_bundle(self.names).to_bytes()
            if self.spec.search.warmup_epochs:
                parent, warmup = self.warm_up(state, parent)
            finished = False
        else:
            k, state = last.index + 1, self.parse(last.winner_state)
            parent = self.artifacts.get(last.artifact_key)
            self.stop_reason = last.stop_reason
            finished = last.converged or self.stop_reason is not None
        while not finished and k < self.spec.search.max_rounds:
            self.check_cancel()
            started = time.time()
            result = self.search_round(k, state, parent)
            winner = result.winner
            finished = winner.task.state == self.format(state)
            stop = None if finished else self.good_enough(state, winner, result.reports)
            self.commit(k, state, dataclasses.replace(result, warmup=warmup if k == 0 else None, stop_reason=stop),
                        started)
            self.charge()
            if stop:
                self.stop_reason, finished = stop, True
            state, parent = self.parse(winner.task.state), winner.bundle
            self.emit(RUNNING, round=k, done=len(result.reports), total=len(result.reports), best=self.loss(winner),
                      state=winner.task.state, message="converged" if finished else "committed")
            k += 1
        outcome = CONVERGED if finished and self.stop_reason is None else STOPPED
        if self.spec.search.polish_epochs:
            self.polish(k, state, parent, outcome)
        self.jobs.set_status(self.job_id, outcome, reason="stop_when" if self.stop_reason else None)

    def prepare(self) -> None:
        """Materialise (or read from the cache) the job's dataset and hand it to the executor.

        Cancelling (or stopping the service) interrupts it between materials. Each start is
        recorded first: a preparation that was started ``MAX_PREPARE_ATTEMPTS`` times and never
        finished (the process died in it, e.g. out of memory) fails the job instead of killing the
        service again on every restart."""
        started = self.jobs.get_job(self.job_id).unfinished_preparations
        if started >= MAX_PREPARE_ATTEMPTS:
            raise RuntimeError(f"preparing the dataset started {started} times and never finished (the "
                               "service died while preparing it, e.g. out of memory); not retried")
        self.jobs.begin_preparation(self.job_id)
        try:
            data, data_key = prepare_dataset(self.spec, self.artifacts, check=self.check_cancel)
        except Interrupted:
            self.jobs.end_preparation(self.job_id, EventKind.PREPARATION_INTERRUPTED)
            raise
        self.jobs.end_preparation(self.job_id, EventKind.DATASET, {
            "key": data_key, "materials": len(data.names), "train": len(data.train), "val": len(data.val),
            "bytes": data.nbytes})
        self.names = data.names
        self.dataset = self.executor.put_dataset(data)

    def wait_for_resources(self, poll_s: float = 1.0) -> None:
        """Until some node of the cluster can hold one candidate (``resources``): at once on a
        fixed cluster (the service refuses such jobs at submission), a while on an autoscaling one.
        After ``resource_wait_s`` the job fails with what is missing, instead of waiting forever
        with every later job queued behind it."""
        deadline = time.monotonic() + self.resource_wait_s
        while missing := self.executor.cluster().missing(self.resources):
            if time.monotonic() >= deadline:
                raise RuntimeError(f"no node of the cluster could hold a candidate within {self.resource_wait_s:g} s "
                                   f"(NEUENH_RESOURCE_WAIT_S): {'; '.join(missing)}")
            self.check_cancel()
            time.sleep(min(poll_s, max(0.0, deadline - time.monotonic())))

    def warm_up(self, state, parent: bytes) -> tuple[bytes, WarmupRecord]:
        """The starting state trained ``warmup_epochs`` (seeded as round -1, so a resumed job warms
        up exactly as before); returns the trained bundle and what round 0's record says of it."""
        task = CandidateTask(self.format(state), candidate_seed(self.spec.train.seed, -1, state),
                             self.spec.search.warmup_epochs)
        [report] = self.train(0, [parent], [task], self.train_config, phase="warmup")
        if not report.ok:
            raise RuntimeError(f"warm-up of {task.state} failed: {report.error}")
        return report.bundle, WarmupRecord(epochs=report.epochs, train_loss=report.train_loss,
                                           val_loss=report.val_loss, wall_s=report.wall_s, node=report.node)

    def search_round(self, k: int, state, parent: bytes) -> RoundResult:
        """Round ``k``: every state of the Hamming ball around ``state``, trained from ``parent``."""
        states = hamming_ball(state, self.spec.search.radius, self.digits, self.constraints)
        epochs = self.spec.search.epochs_per_round
        tasks = [CandidateTask(self.format(s), candidate_seed(self.spec.train.seed, k, s), epochs) for s in states]
        self.jobs.append_event(self.job_id, EventKind.ROUND_STARTED, {"round": k, "state": self.format(state),
                                                              "candidates": len(tasks)})
        trained = self.pruning.train_round(
            lambda parents, tasks, phase: self.train(k, parents, tasks, self.train_config, phase=phase),
            lambda reports: [self.format(s) for s in keep_better_half(self.outcomes(reports),
                                                                      self.spec.search.complexity_weight)],
            parent, tasks)
        reports = trained.reports
        choice = select(self.outcomes([r for r in reports if r.task.state not in trained.pruned]), state,
                        complexity_weight=self.spec.search.complexity_weight,
                        min_improvement=self.spec.search.min_improvement)
        if choice is None:
            errors = "; ".join(f"{r.task.state}: {r.error}" for r in reports[:3])
            raise RuntimeError(f"round {k}: every candidate failed ({errors})")
        winner = next(r for r in reports if r.task.state == self.format(choice.state))
        return RoundResult(winner, reports, trained.halving, trained.pruned)

    def polish(self, k: int, state, parent: bytes, outcome: JobStatus) -> None:
        """The final state trained ``polish_epochs`` more with a decaying lr, committed as round
        ``k`` of kind POLISH recording the search's ``outcome`` (so a job resumed after this commit
        only sets its status)."""
        self.check_cancel()
        started = time.time()
        name = self.format(state)
        task = CandidateTask(name, candidate_seed(self.spec.train.seed, k, state), self.spec.search.polish_epochs)
        [report] = self.train(k, [parent], [task], self.spec.polish_config(), phase="polish")
        if not report.ok:
            raise RuntimeError(f"polishing {name} failed: {report.error}")
        self.commit(k, state, RoundResult(report, [report], kind=RoundKind.POLISH, outcome=outcome), started)
        self.emit(RUNNING, round=k, done=1, total=1, best=self.loss(report), state=name, message="polished")

    # -- steps ---------------------------------------------------------------------------------
    def train(self, k: int, parents: list[bytes], tasks: list[CandidateTask], config,
              phase: str = "train") -> list[CandidateReport]:
        """Every task trained; reports in the tasks' order. Tasks that finished before a restart
        are read back from the store (``recover``); the others go to the executor, and each report
        is persisted as it arrives, so a crash loses only the candidates still in flight."""
        reports = self.recover(k, phase, tasks)
        todo = [t for t in tasks if t.state not in {r.task.state for r in reports}]
        best = min((self.loss(r) for r in reports if r.ok and math.isfinite(self.loss(r))), default=None)
        self.emit(RUNNING, round=k, done=len(reports), total=len(tasks), best=best, message=phase)
        cancelled = lambda: self.should_stop() or self.cancel_requested() or self.budget_spent() is not None  # noqa: E731
        limit = (lambda unfinished: self.share.limit(self.job_id, self.resources, unfinished)) if self.share else unlimited
        try:
            request = TrainRequest(self.dataset, parents, todo, config, self.resources, owner=self.job_id)
            for report in self.executor.train(request, cancelled=cancelled, limit=limit):
                self.persist(k, phase, report)
                reports.append(report)
                if report.ok and math.isfinite(self.loss(report)) and (best is None or self.loss(report) < best):
                    best = self.loss(report)
                self.emit(RUNNING, round=k, done=len(reports), total=len(tasks), best=best, state=report.task.state,
                          message=phase)
        finally:
            if self.share:
                self.share.leave(self.job_id)
        if len(reports) < len(tasks):
            self.check_cancel()
            raise RuntimeError(f"round {k}: the executor returned {len(reports)} of {len(tasks)} candidates")
        order = {t.state: i for i, t in enumerate(tasks)}
        return sorted(reports, key=lambda r: order[r.task.state])  # ball order, not completion order

    def recover(self, k: int, phase: str, tasks: list[CandidateTask]) -> list[CandidateReport]:
        """The reports of ``tasks`` that finished in an earlier run of round ``k`` (same state, seed
        and epochs), their bundles read back (and verified) from the ArtifactStore."""
        wanted = {(t.state, t.seed, t.epochs): t for t in tasks}
        reports = []
        for finished in self.jobs.finished_candidates(self.job_id, k):
            c = finished.candidate
            task = wanted.get((c.state, c.seed, c.epochs)) if finished.phase == phase else None
            if task is None:
                continue
            bundle = self.artifacts.get(finished.artifact_key) if finished.artifact_key else None
            nan = float("nan")
            reports.append(CandidateReport(task, nan if c.train_loss is None else c.train_loss,
                                           nan if c.val_loss is None else c.val_loss, c.epochs, c.wall_s,
                                           c.node or "unknown", error=c.error, bundle=bundle, fit_score=c.fit_score,
                                           fit_score_s=c.extra.get("fit_score_s", 0.0)))
        if reports:
            self.recovered[k] = self.recovered.get(k, 0) + len(reports)
            log.info("job %s: round %d (%s): %d of %d candidates recovered from before the restart",
                     self.job_id, k, phase, len(reports), len(tasks))
        return reports

    def persist(self, k: int, phase: str, report: CandidateReport) -> None:
        """A finished candidate, durably (its bundle first, content-addressed), then in one store
        transaction its record, what it cost and its event."""
        key = self.artifacts.put_content(report.bundle) if report.ok else None
        finished = FinishedCandidate(k, phase, _candidate_record(report, False), key)
        now = time.monotonic()
        self.charged(now, self.jobs.record_candidate(self.job_id, finished, wall_s=now - self.charged_at,
                                                     cpu_s=report.wall_s * self.resources.cpus))

    def loss(self, report: CandidateReport) -> float:
        """What selects (``search.score``): the candidate's validation loss, or its fit score on the
        held-out materials (NaN when it has none: not eligible)."""
        return self.score.loss(report)

    def outcomes(self, reports: list[CandidateReport]) -> list[Outcome]:
        """What the selection rule compares: each state's loss (``loss``), cost and failure."""
        weight = self.spec.search.complexity_weight
        return [Outcome(self.parse(r.task.state), self.loss(r), self.costs.cost(r) if weight and r.ok else 0.0,
                        failed=not r.ok)
                for r in reports]

    def good_enough(self, state, winner: CandidateReport, reports: list[CandidateReport]) -> str | None:
        """Why ``search.stop_when`` ends the search after this round (None: go on)."""
        stop = self.spec.search.stop_when
        if stop is None:
            return None
        loss, what = self.loss(winner), self.score.name
        if stop.val_loss_below is not None and loss <= stop.val_loss_below:
            return f"{what} {loss:.5g} <= val_loss_below {stop.val_loss_below:g}"
        stay = next((r for r in reports if r.task.state == self.format(state) and r.ok), None)
        if stop.gain_below is not None and stay is not None and math.isfinite(self.loss(stay)):
            gain = 1.0 - loss / self.loss(stay)
            if gain < stop.gain_below:
                return f"gain {100 * gain:.2f} % over stay < gain_below {100 * stop.gain_below:g} %"
        return None

    def commit(self, k: int, state, result: RoundResult, started: float) -> None:
        """Round ``k``'s winner checkpoint, durably, then the round itself in one transaction. The
        checkpoint is content-addressed: the round record holds its SHA-256 (the key), and every
        read re-hashes it, so a changed byte is an error naming it, never a silently wrong model."""
        winner = result.winner
        key = self.artifacts.put_content(winner.bundle)  # durable before the round becomes visible
        self.jobs.commit_round(self.job_id, RoundRecord(
            index=k, parent_state=self.format(state), winner_state=winner.task.state,
            candidates=tuple(_candidate_record(r, r.task.state in result.pruned) for r in result.reports),
            started_at=started, finished_at=time.time(), artifact_key=key, kind=result.kind, outcome=result.outcome,
            warmup=result.warmup, halving=result.halving, recovered=self.recovered.get(k, 0),
            stop_reason=result.stop_reason,
        ))

    # -- cancellation, budget and progress ---------------------------------------------------------
    def cancel_requested(self) -> bool:
        return self.jobs.get_job(self.job_id).status == CANCELLED

    def check_cancel(self) -> None:
        if self.should_stop():
            raise Interrupted()
        if self.cancel_requested():
            raise Cancelled()
        if (spent := self.budget_spent()) is not None:
            raise BudgetSpent(spent)

    def charge(self) -> None:
        """Add the wall time since the last charge to the job's stored usage."""
        now = time.monotonic()
        self.charged(now, self.jobs.charge(self.job_id, wall_s=now - self.charged_at))

    def charged(self, at: float, job: JobRecord) -> None:
        """The job's usage as stored by a charge made at ``at`` (``time.monotonic``)."""
        self.charged_at, self.used_wall_s, self.used_cpu_s = at, job.used_wall_s, job.used_cpu_s

    def budget_spent(self) -> str | None:
        """What of the budget ran out (None while it lasts); the wall time counts live."""
        budget = self.spec.budget
        if not self.enforce_budget:
            return None
        wall = self.used_wall_s + time.monotonic() - self.charged_at
        if budget.wall_s is not None and wall >= budget.wall_s:
            return f"wall time {wall:.1f} s of budget.wall_s {budget.wall_s:g} s"
        if budget.cpu_s is not None and self.used_cpu_s >= budget.cpu_s:
            return f"CPU time {self.used_cpu_s:.1f} s of budget.cpu_s {budget.cpu_s:g} s"
        return None

    def emit(self, status: JobStatus, *, round: int = -1, done: int = 0, total: int = 0,
             best: float | None = None, state: str = "", message: str = "") -> None:
        self.on_progress(Progress(self.job_id, status, round, done, total, best, state,
                                  time.perf_counter() - self.clock, message, self.score.label))

    def parse(self, state: str):
        return self.graph.parse_state(state, self.digit_counts)

    def format(self, digits) -> str:
        return self.graph.format_state(digits)


def _candidate_record(r: CandidateReport, pruned: bool) -> CandidateRecord:
    return CandidateRecord(
        state=r.task.state, train_loss=r.train_loss, val_loss=r.val_loss, epochs=r.epochs, wall_s=r.wall_s,
        node=r.node, error=r.error if r.error or not pruned else PRUNED, seed=r.task.seed, pruned=pruned,
        fit_score=r.fit_score, extra={"fit_score_s": round(r.fit_score_s, 3)} if r.fit_score_s else {},
    )
