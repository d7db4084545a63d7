"""Budgets: a job stops at its last committed round, STOPPED with reason "budget", as soon as a
finished candidate (or, for the wall time, the clock) uses it up; what it used survives restarts."""

import dataclasses
import time

import pytest

from neuenh_service.orchestrator.runner import Orchestrator
from neuenh_service.storage import JobStatus
from neuenh_service.workers.inline import InlineExecutor

from jobspecs import tiny_spec


class _Crash(BaseException):
    """The process dying (not an Exception: nothing in the orchestrator catches it)."""


class Metered(InlineExecutor):
    """Every candidate reports ``wall_s`` seconds of training (so CPU use is exact), optionally
    sleeping ``sleep_s`` first; the process "dies" after ``crash_after`` reports."""

    def __init__(self, wall_s=1.0, sleep_s=0.0, crash_after=None):
        super().__init__()
        self.wall_s, self.sleep_s, self.crash_after, self.trained = wall_s, sleep_s, crash_after, 0

    def train(self, *args, **kwargs):
        for report in super().train(*args, **kwargs):
            time.sleep(self.sleep_s)
            if self.crash_after is not None and self.trained >= self.crash_after:
                raise _Crash()
            self.trained += 1
            yield dataclasses.replace(report, wall_s=self.wall_s)


def budget_spec(**budget):
    return tiny_spec(max_rounds=3).model_copy(update={"budget": tiny_spec().budget.model_copy(update=budget)})


def test_a_cpu_budget_spent_mid_round_stops_at_the_last_commit(stores):
    jobs, artifacts = stores
    o = Orchestrator(jobs, artifacts, Metered(wall_s=1.0))
    job = o.run(o.submit(budget_spec(cpu_s=17.0))[0].id)  # 12 candidates of round 0, then 5 of round 1
    assert (job.status, job.reason, job.error) == (JobStatus.STOPPED, "budget", None)
    assert job.last_round == 0 and job.used_cpu_s == 17.0
    assert len(jobs.finished_candidates(job.id, 1)) == 5  # trained, persisted, never committed
    [spent] = [e for e in jobs.events(job.id) if e.kind == "budget_spent"]
    assert "CPU time 17.0 s of budget.cpu_s 17 s" in spent.payload["detail"]


def test_what_a_job_used_counts_after_a_restart(stores):
    jobs, artifacts = stores
    crashing = Orchestrator(jobs, artifacts, Metered(wall_s=1.0, crash_after=15))  # 3 into round 1
    job, _ = crashing.submit(budget_spec(cpu_s=20.0))
    with pytest.raises(_Crash):
        crashing.run(job.id)
    assert jobs.get_job(job.id).used_cpu_s == 15.0 and jobs.get_job(job.id).status is JobStatus.RUNNING

    resumed = Metered(wall_s=1.0)
    final = Orchestrator(jobs, artifacts, resumed).run(job.id)
    assert resumed.trained == 5  # 20 - 15: the 3 recovered candidates are not charged twice
    assert (final.status, final.reason, final.used_cpu_s, final.last_round) == (JobStatus.STOPPED, "budget", 20.0, 0)


def test_the_wall_budget_stops_candidates_in_flight(stores):
    jobs, artifacts = stores
    slow = Metered(sleep_s=0.1)
    started = time.monotonic()
    job = Orchestrator(jobs, artifacts, slow).run(Orchestrator(jobs, artifacts, slow).submit(budget_spec(wall_s=0.8))[0].id)
    assert (job.status, job.reason) == (JobStatus.STOPPED, "budget")
    assert job.last_round is None and slow.trained < 12  # round 0 (12 candidates x 0.1 s) never finished
    assert 0.8 <= job.used_wall_s < time.monotonic() - started + 0.01


def test_without_a_budget_usage_is_still_recorded(stores):
    jobs, artifacts = stores
    o = Orchestrator(jobs, artifacts, Metered(wall_s=0.5))
    job = o.run(o.submit(tiny_spec(max_rounds=2))[0].id)
    assert job.reason is None and job.status in (JobStatus.CONVERGED, JobStatus.STOPPED)
    assert job.used_cpu_s == 0.5 * sum(len(r.candidates) for r in jobs.rounds(job.id))
    assert job.used_wall_s > 0
