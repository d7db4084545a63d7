"""One service, many searches, on the real embedded Ray through ``neuenh serve``: jobs run at once
and share the cluster, queued ones start by priority, and a crash mid-round costs only the
candidates that were still training."""

from __future__ import annotations

import json
import signal
import time

import pytest

from neuenh_service.storage import SQLiteJobStore

from jobspecs import run_alone, run_alone_soon, served_path, tiny_spec
from live_api import TERMINAL, wait_for
from serve_process import ServeProcess


def status_times(store: SQLiteJobStore, job_id: str) -> dict[str, float]:
    return {e.payload["status"]: e.time for e in store.events(job_id) if e.kind == "status"}


def test_jobs_run_at_once_share_the_cluster_and_start_by_priority(tmp_path):
    specs = []
    for seed in range(5):
        spec = tiny_spec(max_rounds=2, epochs_per_round=2).model_dump(mode="json")
        spec["train"]["seed"], spec["name"] = seed, f"job-{seed}"
        specs.append(spec)
    specs[4]["priority"] = 5  # submitted last, it must start before job-3, queued before it
    references = run_alone_soon(tmp_path, specs)
    server = ServeProcess(tmp_path / "data", env={"NEUENH_MAX_RUNNING_JOBS": "3", "NEUENH_LOG_FORMAT": "json"}).wait_ready()
    try:
        with server.client() as c:
            ids = [c.post("/jobs", json=spec).json()["id"] for spec in specs]
            holders_seen, cluster = 0, None
            while not all(c.get(f"/jobs/{i}").json()["terminal"] for i in ids):
                cluster = c.get("/cluster").json()
                holders_seen = max(holders_seen, len(cluster["holders"]))
                assert len(cluster["running_jobs"]) <= 3 == cluster["max_running_jobs"]
                time.sleep(0.1)
            finals = [wait_for(c, i) for i in ids]
            histories = [c.get(f"/jobs/{i}/history").json() for i in ids]
    finally:
        server.stop()
    assert all(j["status"] in ("CONVERGED", "STOPPED") and j["error"] is None for j in finals), finals
    logged = [json.loads(line) for line in server.lines if line.startswith("{")]  # NEUENH_LOG_FORMAT=json
    ours = [entry for entry in logged if entry["logger"].startswith("neuenh")]
    assert {f"job {i}: {j['status']}" for i, j in zip(ids, finals)} <= {entry["message"] for entry in ours}
    assert all({"time", "level", "logger", "message"} <= set(entry) for entry in logged)
    assert not [line for line in server.lines if " INFO neuenh" in line], "a text log line"
    assert holders_seen >= 2, "two jobs never trained candidates at the same time"
    with SQLiteJobStore(tmp_path / "data" / "jobs.sqlite") as store:
        times = [status_times(store, i) for i in ids]
    end = lambda t: t.get("CONVERGED", t.get("STOPPED"))  # noqa: E731
    first_three = times[:3]
    assert max(t["RUNNING"] for t in first_three) < min(end(t) for t in first_three), "the three did not overlap"
    assert times[4]["PREPARING"] < times[3]["PREPARING"], "the high-priority job did not start first"
    for spec, history, alone in zip(specs, histories, references.result(timeout=300)):
        assert served_path(history) == alone, spec["name"]


# ~0.3 s a candidate alone (2 materials of 4,000 samples, 5 epochs): the store is polled every
# 20 ms, so the service is killed while the round's other candidates are still training; two rounds:
# both crashes come in round 0 or 1, and the job must go on after them.
LONG = tiny_spec(max_rounds=2, epochs_per_round=5).model_dump(mode="json")
LONG["data"][0]["samples"] = 4000


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    return run_alone(tmp_path_factory.mktemp("alone"), LONG)


def crash_after(server: ServeProcess, store: SQLiteJobStore, job_id: str, k: int) -> tuple[int, int, int]:
    """Wait until the round in progress has ``k`` finished candidates (persisted as they finish), then
    SIGKILL the service: a crash, no shutdown, no chance to tidy up. Returns the interrupted round,
    how many of its candidates the store holds and the last event's seq."""
    deadline = time.monotonic() + 300  # a guard against a hang; minutes on an overloaded machine
    try:
        while len(store.finished_candidates(job_id, store.get_job(job_id).next_round)) < k:
            assert time.monotonic() < deadline and not store.get_job(job_id).terminal, server.output
            time.sleep(0.02)
    finally:
        server.stop(signal.SIGKILL)
    interrupted = store.get_job(job_id).next_round
    assert not store.get_job(job_id).terminal
    return interrupted, len(store.finished_candidates(job_id, interrupted)), store.events(job_id)[-1].seq


def test_crashes_mid_round_retrain_only_the_unfinished_candidates(tmp_path, uninterrupted):
    """Killed after 3 finished candidates of the round in progress, restarted, killed again once 8 of
    the round then in progress had finished, restarted: each restart trains only what the store did
    not hold, and the job reaches what a run that never crashed reaches."""
    assert len(uninterrupted) == 2, "the job must go on after round 0"
    server = ServeProcess(tmp_path / "data").wait_ready()
    try:
        with server.client() as c:
            job_id = c.post("/jobs", json=LONG).json()["id"]
    except BaseException:
        server.stop(signal.SIGKILL)
        raise
    store = SQLiteJobStore(tmp_path / "data" / "jobs.sqlite")
    crashes = [crash_after(server, store, job_id, 3)]
    before = store.rounds(job_id)

    again = ServeProcess(tmp_path / "data").wait_ready()
    crashes.append(crash_after(again, store, job_id, 8))
    assert f"resuming 1 unfinished job(s): {job_id}" in again.output

    last = ServeProcess(tmp_path / "data").wait_ready()
    try:
        with last.client() as c:
            job = wait_for(c, job_id, timeout=240)
            after = c.get(f"/jobs/{job_id}/history").json()
    finally:
        assert last.stop() in (0, -signal.SIGTERM), last.output
    assert job["status"] in ("CONVERGED", "STOPPED") and job["error"] is None, job
    for interrupted, finished, last_seq in crashes:
        assert finished >= 1
        retrained = [e for e in store.events(job_id, after_seq=last_seq)
                     if e.kind == "candidate" and e.payload["round"] == interrupted]
        assert len(retrained) == 12 - finished, (interrupted, finished)
    (first_round, first_finished, _), (second_round, second_finished, _) = crashes
    assert after["rounds"][second_round]["recovered"] == second_finished
    if first_round != second_round:
        assert after["rounds"][first_round]["recovered"] == first_finished
    assert store.rounds(job_id)[: len(before)] == before, "a committed round changed"
    assert served_path(after) == uninterrupted  # the same states and losses as a run that never crashed
    store.close()
