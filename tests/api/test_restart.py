"""Stopping the service mid-job does not fail or cancel the job: the next start resumes it from
its last committed round and runs it to the end."""

from __future__ import annotations

from jobspecs import tiny_spec
from live_api import wait_for

from neuenh_service.storage import SQLiteJobStore


# Rounds of ~1.3 s alone (30 epochs: 3.8 s for the three; at one epoch the whole job took 0.5 s and
# once ended before the stop below, which follows the first committed round by a poll of 0.1 s): the
# stop lands mid-job.
SPEC = tiny_spec(max_rounds=3, epochs_per_round=30).model_dump(mode="json")


def test_stop_mid_job_then_resume(live_server, tmp_path):
    first = live_server()
    with first.client() as c:
        job_id = c.post("/jobs", json=SPEC).json()["id"]
        wait_for(c, job_id, until=lambda job: job["last_round"] is not None or job["terminal"])
    first.stop()

    with SQLiteJobStore(tmp_path / "data" / "jobs.sqlite") as store:
        stored = store.get_job(job_id)
    assert not stored.terminal and stored.error is None, stored
    assert stored.last_round is not None and stored.last_round < 2

    second = live_server()  # same data_dir: the worker resumes unfinished jobs at start
    with second.client() as c:
        job = wait_for(c, job_id)
        history = c.get(f"/jobs/{job_id}/history").json()
    assert job["status"] in ("STOPPED", "CONVERGED") and job["error"] is None
    rounds = history["rounds"]
    assert [r["round"] for r in rounds] == list(range(len(rounds)))
    assert all(b["parent_state"] == a["winner_state"] for a, b in zip(rounds, rounds[1:]))
