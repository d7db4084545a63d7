"""The job state machine (ARCHITECTURE §3):

    QUEUED -> PREPARING -> RUNNING (round k) -> CONVERGED | STOPPED | CANCELLED | FAILED

Round k trains every admissible state within the spec's radius of the current state B_c (each from
B_c's trained weights, with a seed fixed by (job seed, k, state)), picks the winner with
``neuenh.search.select``, writes the winner's checkpoint to the ArtifactStore, and only then
commits the round (every candidate, the winner, timings) to the JobStore in one transaction: a
round is visible only once both are durable. "Stay" winning ends the job as CONVERGED. With
``search.polish_epochs`` the final state then trains once more (lr decaying) as one last round of
kind POLISH, which records the search's outcome, before the status is set.

After a crash ``run`` picks a job up from its last committed round; the interrupted round is
re-run with the same seeds, so the outcome equals an uninterrupted run. Candidates of that round
that had finished before the crash were persisted as they arrived and are read back, not re-run.
A job's usage (wall time, CPU time of its candidates) is stored as it grows; when its ``budget``
runs out it stops at its last committed round, STOPPED with reason "budget". Cancellation (the job's
status set to CANCELLED in the store, from any process) stops the running candidates and leaves
the job at its last committed round.

``Orchestrator`` holds the entry points; each job's run is a ``job_run.JobRun``.
"""

from __future__ import annotations

import logging
import traceback
from typing import Callable

from neuenh.data.samples import TrainingData
from neuenh.train import CandidateResult, train_candidate
from neuenh_service.storage import ArtifactStore, EventKind, JobStatus, JobStore

from .executor import Executor
from .job_run import BudgetSpent, Cancelled, Interrupted, JobRun
from .progress import Progress
from .shares import FairShare
from .spec import JobSpec, parse_spec

log = logging.getLogger("neuenh.orchestrator")

__all__ = ["Orchestrator", "Progress", "train_plain_baseline"]


class Orchestrator:
    """Runs jobs to a terminal state. Stores and executor are built by the caller and passed in."""

    def __init__(self, jobs: JobStore, artifacts: ArtifactStore, executor: Executor,
                 on_progress: Callable[[Progress], None] | None = None,
                 should_stop: Callable[[], bool] = lambda: False, resource_wait_s: float = 600.0,
                 share: FairShare | None = None):
        """``should_stop``: polled like cancellation; when it turns true the running job stops at
        its next safe point without any change to its record (a service shutting down).
        ``resource_wait_s``: how long a job waits for a node that can hold one of its candidates
        (an autoscaling cluster growing) before it fails with the reason. ``share``: divides the
        cluster between jobs that ``run`` at once (from several threads); None: no cap."""
        self.resource_wait_s = resource_wait_s
        self.share = share
        self.jobs = jobs
        self.artifacts = artifacts
        self.executor = executor
        self.on_progress = on_progress or (lambda p: None)
        self.should_stop = should_stop

    def submit(self, spec: JobSpec, idempotency_key: str | None = None, owner: str | None = None):
        """Store a validated spec as a QUEUED job of ``owner``; returns (job, created) as
        ``JobStore.create_job``."""
        return self.jobs.create_job(spec.model_dump(mode="json"), idempotency_key=idempotency_key, owner=owner)

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
        run = None
        try:
            run = JobRun(job_id, parse_spec(job.spec), self.jobs, self.artifacts, self.executor,
                         self.on_progress, self.should_stop, self.resource_wait_s, self.share)
            try:
                run.execute()
            finally:
                run.charge()
        except Cancelled:
            run.emit(JobStatus.CANCELLED, message="cancelled")
        except Interrupted:
            run.emit(self.jobs.get_job(job_id).status, message="interrupted")
        except BudgetSpent as spent:
            log.info("job %s: budget spent (%s); stopped at its last committed round", job_id, spent)
            self.jobs.append_event(job_id, EventKind.BUDGET_SPENT, {"detail": str(spent)})
            self.jobs.set_status(job_id, JobStatus.STOPPED, reason="budget")
            run.emit(JobStatus.STOPPED, message=f"budget: {spent}")
        except Exception as exc:  # any failure ends the job FAILED with its reason, never silently
            if self.jobs.get_job(job_id).status is JobStatus.CANCELLED:
                # a cancel that raced a step (e.g. a commit refused by the CANCELLED status): the
                # job ended as asked; nothing failed
                log.info("job %s: cancelled during %s: %s", job_id, type(exc).__name__, exc)
                return self.jobs.get_job(job_id)
            log.error("job %s failed:\n%s", job_id, traceback.format_exc())
            if not self.jobs.get_job(job_id).terminal:
                self.jobs.set_status(job_id, JobStatus.FAILED, error=f"{type(exc).__name__}: {exc}")
        return self.jobs.get_job(job_id)


def train_plain_baseline(spec: JobSpec, data: TrainingData, epochs: int) -> CandidateResult:
    """The analytical model trained as long as a search trained in total: the fair baseline
    against which an enhancement's gain is measured."""
    parent = spec.initial_bundle(data.names)
    return train_candidate(parent, "0" * len(parent.model.positions), data, spec.train_config(epochs),
                           spec.train.seed)
