"""The job state machine (DESIGN §3):

    QUEUED -> PREPARING -> RUNNING (round k) -> CONVERGED | STOPPED | CANCELLED | FAILED

Round k trains every admissible state within the spec's radius of the current state B_c (each from
B_c's trained weights, with a seed fixed by (job seed, k, state)), picks the winner with
``neuenh.search.select``, writes the winner's checkpoint to the ArtifactStore, and only then
commits the round (every candidate, the winner, timings) to the JobStore in one transaction: a
round is visible only once both are durable. "Stay" winning ends the job as CONVERGED. With
``search.polish_epochs`` the final state then trains once more (lr decaying) as one last round,
``extra.polish`` holding the outcome, before the status is set.

After a crash ``run`` picks a job up from its last committed round; the interrupted round is
re-run with the same seeds, so the outcome equals an uninterrupted run. Cancellation (the job's
status set to CANCELLED in the store, from any process) stops the running candidates and leaves
the job at its last committed round.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
import time
import traceback
from dataclasses import dataclass
from typing import Callable

from neuenh.graph import Graph
from neuenh.models import get_model
from neuenh.train import CandidateResult, TrainingData, train_candidate
from neuenh.search import Outcome, candidate_seed, hamming_ball, initial_state, keep_better_half, select, weight_cost
from storage import ArtifactStore, CandidateRecord, JobStatus, JobStore, RoundRecord, checkpoint_key

from .dataset import prepare_dataset
from .executor import CandidateReport, CandidateTask, Executor, Resources
from .spec import JobSpec, parse_spec

log = logging.getLogger("neuenh.orchestrator")

QUEUED, PREPARING, RUNNING = JobStatus.QUEUED, JobStatus.PREPARING, JobStatus.RUNNING
CONVERGED, STOPPED, CANCELLED, FAILED = JobStatus.CONVERGED, JobStatus.STOPPED, JobStatus.CANCELLED, JobStatus.FAILED


@dataclass(frozen=True)
class Progress:
    """What a progress display needs, sent to ``on_progress`` as a job moves."""

    job_id: str
    status: str
    round: int
    done: int
    total: int
    best_val_loss: float | None
    state: str
    elapsed_s: float
    message: str = ""


class _Cancelled(Exception):
    """The job was cancelled (its status is CANCELLED in the store)."""


class _Interrupted(Exception):
    """This process is stopping: the job is left as it is and resumes on the next start."""


class Orchestrator:
    """Runs jobs to a terminal state. Stores and executor are built by the caller and passed in."""

    def __init__(self, jobs: JobStore, artifacts: ArtifactStore, executor: Executor,
                 on_progress: Callable[[Progress], None] | None = None,
                 should_stop: Callable[[], bool] = lambda: False):
        """``should_stop``: polled like cancellation; when it turns true the running job stops at
        its next safe point without any change to its record (a service shutting down)."""
        self.jobs = jobs
        self.artifacts = artifacts
        self.executor = executor
        self.on_progress = on_progress or (lambda p: None)
        self.should_stop = should_stop

    # -- entry points --------------------------------------------------------------------------
    def submit(self, spec: JobSpec, idempotency_key: str | None = None):
        """Store a validated spec as a QUEUED job; returns (job, created) as ``JobStore.create_job``."""
        return self.jobs.create_job(spec.model_dump(mode="json"), idempotency_key=idempotency_key)

    def resume_all(self) -> list[str]:
        """Run every job that is not terminal (after a restart), oldest first."""
        ids = [job.id for job in self.jobs.unfinished_jobs()]
        for job_id in ids:
            self.run(job_id)
        return ids

    def run(self, job_id: str):
        """Drive ``job_id`` until it is terminal (or cancelled); returns the final job record."""
        job = self.jobs.get_job(job_id)
        if job.terminal:
            return job
        start = time.perf_counter()
        try:
            spec = parse_spec(job.spec)
            self._run(job_id, spec, start)
        except _Cancelled:
            self._emit(job_id, CANCELLED, -1, 0, 0, None, "", start, "cancelled")
        except _Interrupted:
            self._emit(job_id, self.jobs.get_job(job_id).status, -1, 0, 0, None, "", start, "interrupted")
        except Exception as exc:  # any failure ends the job FAILED with its reason, never silently
            log.error("job %s failed:\n%s", job_id, traceback.format_exc())
            if not self.jobs.get_job(job_id).terminal:
                self.jobs.set_status(job_id, FAILED, error=f"{type(exc).__name__}: {exc}")
        return self.jobs.get_job(job_id)

    # -- the state machine ---------------------------------------------------------------------
    def _run(self, job_id: str, spec: JobSpec, start: float) -> None:
        if self.jobs.get_job(job_id).status == QUEUED:
            self.jobs.set_status(job_id, PREPARING)
        self._check_cancel(job_id)
        data, data_key = prepare_dataset(spec, self.artifacts)
        self.jobs.append_event(job_id, "dataset", {"key": data_key, "materials": len(data.names),
                                                 "train": len(data.train), "val": len(data.val),
                                                 "bytes": data.nbytes})
        if self.jobs.get_job(job_id).status == PREPARING:
            self.jobs.set_status(job_id, RUNNING)
        dataset = self.executor.put_dataset(data)

        graph = get_model(spec.model).graph
        m, constraints = spec.digits(), spec.constraints()
        last = self.jobs.last_round(job_id)
        warmup: dict = {}
        finished = False  # the search itself is over (converged or out of rounds)
        if last is None:
            round_index = 0
            state = initial_state(len(graph), m, constraints)
            parent = spec.initial_bundle(data.names).to_bytes()
            if spec.search.warmup_epochs:
                parent, warmup = self._warm_up(job_id, spec, state, parent, dataset, start)
        else:
            if last.extra.get("polish"):  # crashed after the last commit, before the status
                self.jobs.set_status(job_id, CONVERGED if last.extra["polish"] == CONVERGED.value else STOPPED)
                return
            round_index = last.index + 1
            state = graph.parse_state(last.winner_state, m)
            parent = self.artifacts.get(last.artifact_key)
            finished = last.winner_state == last.parent_state
        outcome = CONVERGED if finished else STOPPED
        while not finished and round_index < spec.search.max_rounds:
            self._check_cancel(job_id)
            started = time.time()
            winner, reports, extra = self._round(job_id, spec, round_index, state, parent, dataset, start)
            if round_index == 0 and warmup:
                extra = {**extra, "warmup": warmup}
            self._commit(job_id, round_index, state, winner, reports, extra, started)
            finished = winner.task.state == Graph.format_state(state)
            outcome = CONVERGED if finished else STOPPED
            state, parent = graph.parse_state(winner.task.state, m), winner.bundle
            self._emit(job_id, RUNNING, round_index, len(reports), len(reports), winner.val_loss,
                       winner.task.state, start, "converged" if finished else "committed")
            round_index += 1
        if spec.search.polish_epochs:
            self._polish(job_id, spec, round_index, state, parent, dataset, start, outcome)
        self.jobs.set_status(job_id, outcome)

    def _commit(self, job_id, k: int, state, winner: CandidateReport, reports, extra: dict, started: float) -> None:
        """Round ``k``'s winner checkpoint, durably, then the round itself in one transaction."""
        key = checkpoint_key(job_id, k)
        self.artifacts.put(key, winner.bundle)  # durable before the round becomes visible
        self.jobs.commit_round(job_id, RoundRecord(
            index=k,
            parent_state=Graph.format_state(state),
            winner_state=winner.task.state,
            candidates=tuple(_candidate_record(r, extra) for r in reports),
            started_at=started,
            finished_at=time.time(),
            artifact_key=key,
            extra=extra,
        ))

    def _polish(self, job_id, spec: JobSpec, k: int, state, parent: bytes, dataset, start, outcome) -> None:
        """The final state trained ``polish_epochs`` more with a decaying lr, committed as round
        ``k`` (its only candidate is the final state; ``extra.polish`` holds the search's outcome,
        so a job resumed after this commit only sets its status)."""
        self._check_cancel(job_id)
        started = time.time()
        name = Graph.format_state(state)
        task = CandidateTask(name, candidate_seed(spec.train.seed, k, state), spec.search.polish_epochs)
        resources = Resources(spec.resources.cpus_per_candidate, spec.resources.gpus_per_candidate)
        [report] = self._train(job_id, k, dataset, [parent], [task], spec.polish_config(), resources, start,
                               phase="polish")
        if not report.ok:
            raise RuntimeError(f"polishing {name} failed: {report.error}")
        self._commit(job_id, k, state, report, [report], {"polish": outcome.value}, started)
        self._emit(job_id, RUNNING, k, 1, 1, report.val_loss, name, start, "polished")

    def _warm_up(self, job_id, spec: JobSpec, state, parent: bytes, dataset, start) -> tuple[bytes, dict]:
        """The starting state trained ``warmup_epochs`` (seeded as round -1, so a resumed job warms
        up exactly as before); returns the trained bundle and what round 0's record says of it."""
        task = CandidateTask(Graph.format_state(state), candidate_seed(spec.train.seed, -1, state),
                             spec.search.warmup_epochs)
        resources = Resources(spec.resources.cpus_per_candidate, spec.resources.gpus_per_candidate)
        [report] = self._train(job_id, 0, dataset, [parent], [task], spec.train_config(), resources, start,
                               phase="warmup")
        if not report.ok:
            raise RuntimeError(f"warm-up of {task.state} failed: {report.error}")
        return report.bundle, {"epochs": report.epochs, "train_loss": report.train_loss,
                               "val_loss": report.val_loss, "wall_s": report.wall_s, "node": report.node}

    def _round(self, job_id, spec: JobSpec, k: int, state, parent: bytes, dataset, start):
        m = spec.digits()
        states = hamming_ball(state, spec.search.radius, m, spec.constraints())
        epochs = spec.search.epochs_per_round
        resources = Resources(spec.resources.cpus_per_candidate, spec.resources.gpus_per_candidate)
        config = spec.train_config()
        tasks = [CandidateTask(Graph.format_state(s), candidate_seed(spec.train.seed, k, s), epochs) for s in states]
        self.jobs.append_event(job_id, "round_started", {"round": k, "state": Graph.format_state(state),
                                                      "candidates": len(tasks)})
        extra: dict = {}
        if spec.search.prune == "halving" and len(tasks) > 2:
            first = max(1, round(epochs * spec.search.halving_fraction))
            early = self._train(job_id, k, dataset, [parent], [_with_epochs(t, first) for t in tasks],
                                config, resources, start, phase="halving")
            survivors = keep_better_half(self._outcomes(spec, early), spec.search.complexity_weight)
            by_state = {r.task.state: r for r in early}
            second = [CandidateTask(r.task.state, r.task.seed, epochs - first, parent=i)
                      for i, r in enumerate(by_state[Graph.format_state(s)] for s in survivors)]
            late = self._train(job_id, k, dataset, [by_state[t.state].bundle for t in second], second,
                               config, resources, start, phase="continue")
            late = {r.task.state: dataclasses.replace(r, epochs=r.epochs + first) for r in late}
            pruned = [r for r in early if r.task.state not in late]
            reports = [late.get(r.task.state, r) for r in early]
            extra = {"prune": "halving", "first_epochs": first,
                     "pruned": [r.task.state for r in pruned],
                     "early_val_loss": {r.task.state: r.val_loss for r in early}}
        else:
            reports = self._train(job_id, k, dataset, [parent], tasks, config, resources, start)
        outcomes = self._outcomes(spec, [r for r in reports if r.task.state not in extra.get("pruned", ())])
        choice = select(outcomes, state, complexity_weight=spec.search.complexity_weight,
                        min_improvement=spec.search.min_improvement)
        if choice is None:
            errors = "; ".join(f"{r.task.state}: {r.error}" for r in reports[:3])
            raise RuntimeError(f"round {k}: every candidate failed ({errors})")
        winner = next(r for r in reports if r.task.state == Graph.format_state(choice.state)
                      and r.task.state not in extra.get("pruned", ()))
        return winner, reports, extra

    def _train(self, job_id, k, dataset, parents, tasks, config, resources, start, phase="train"):
        reports: list[CandidateReport] = []
        best = None
        self._emit(job_id, RUNNING, k, 0, len(tasks), None, "", start, phase)
        for report in self.executor.train(dataset, parents, tasks, config, resources,
                                          cancelled=lambda: self.should_stop() or self._cancel_requested(job_id)):
            reports.append(report)
            if report.ok and (best is None or report.val_loss < best):
                best = report.val_loss
            self.jobs.append_event(job_id, "candidate", {"round": k, "phase": phase, **_candidate_row(report)})
            self._emit(job_id, RUNNING, k, len(reports), len(tasks), best, report.task.state, start, phase)
        if len(reports) < len(tasks):
            self._check_cancel(job_id)
            raise RuntimeError(f"round {k}: the executor returned {len(reports)} of {len(tasks)} candidates")
        order = {t.state: i for i, t in enumerate(tasks)}
        return sorted(reports, key=lambda r: order[r.task.state])  # ball order, not completion order

    def _outcomes(self, spec: JobSpec, reports: list[CandidateReport]) -> list[Outcome]:
        m = spec.digits()
        graph = get_model(spec.model).graph
        outcomes = []
        for r in reports:
            digits = graph.parse_state(r.task.state, m)
            cost = weight_cost(neural_weights(spec, r.task.state)) \
                if spec.search.complexity_weight else 0.0
            outcomes.append(Outcome(digits, r.val_loss, cost, failed=not r.ok))
        return outcomes

    # -- cancellation and progress ---------------------------------------------------------------
    def _cancel_requested(self, job_id: str) -> bool:
        return self.jobs.get_job(job_id).status == CANCELLED

    def _check_cancel(self, job_id: str) -> None:
        if self.should_stop():
            raise _Interrupted()
        if self._cancel_requested(job_id):
            raise _Cancelled()

    def _emit(self, job_id, status, k, done, total, best, state, start, message) -> None:
        self.on_progress(Progress(job_id, status, k, done, total, best, state,
                                  time.perf_counter() - start, message))


def trained_epochs(rounds: list[RoundRecord]) -> int:
    """Epochs the last winner has trained in all: each round's winner, plus any warm-up."""
    return rounds[0].extra.get("warmup", {}).get("epochs", 0) + sum(r.winner.epochs for r in rounds)


def train_plain_baseline(spec: JobSpec, data: TrainingData, epochs: int) -> CandidateResult:
    """The analytical model trained as long as a search trained in total: the fair baseline
    against which an enhancement's gain is measured."""
    parent = spec.initial_bundle(data.names)
    return train_candidate(parent, "0" * len(parent.model.positions), data, spec.train_config(epochs),
                           spec.train.seed)


def neural_weights(spec: JobSpec, state: str) -> int:
    """Neural weights of ``state`` of the spec's model (its modules and latent size)."""
    return _n_weights(spec.model, state, spec.module.config(), spec.latent_dim)


@functools.lru_cache(maxsize=4096)
def _n_weights(model: str, state: str, module_config, latent_dim: int) -> int:
    return get_model(model, state=state, module_config=module_config, latent_dim=latent_dim).n_weights()


def _with_epochs(task: CandidateTask, epochs: int) -> CandidateTask:
    return CandidateTask(task.state, task.seed, epochs, task.parent)


def _candidate_row(r: CandidateReport) -> dict:
    """A report as JSON (non-finite losses as None)."""
    finite = lambda x: x if math.isfinite(x) else None  # noqa: E731
    return {"state": r.task.state, "seed": r.task.seed, "train_loss": finite(r.train_loss),
            "val_loss": finite(r.val_loss), "epochs": r.epochs, "wall_s": r.wall_s, "node": r.node,
            "error": r.error}


def _candidate_record(r: CandidateReport, extra: dict) -> CandidateRecord:
    pruned = r.task.state in extra.get("pruned", ())
    return CandidateRecord(
        state=r.task.state, train_loss=r.train_loss, val_loss=r.val_loss, epochs=r.epochs, wall_s=r.wall_s,
        node=r.node, error=r.error if r.error or not pruned else "pruned by successive halving",
        seed=r.task.seed,
    )
