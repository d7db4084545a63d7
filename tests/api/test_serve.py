"""``neuenh serve`` end to end with real parts: uvicorn on loopback, an embedded Ray training the
candidates, SQLite. One owner per store; a crash mid-job loses nothing committed and the restarted
service finishes the job; SIGTERM shuts Ray down and leaves nothing running."""

from __future__ import annotations

import os
import signal
import subprocess
import time


from jobspecs import tiny_spec
from live_api import wait_for
from serve_process import NEUENH, REPO, ServeProcess, clean_env


def alive(pids: set[int]) -> set[int]:
    return {pid for pid in pids if os.path.exists(f"/proc/{pid}") and
            open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()[0] != "Z"}


def test_serve_runs_jobs_on_ray_owns_its_store_and_shuts_down_cleanly(tmp_path):
    server = ServeProcess(tmp_path / "data").wait_ready()
    try:
        with server.client() as c:
            cluster = c.get("/cluster").json()
            assert cluster["backend"] == "ray" and cluster["cpus"] == 2
            [node] = cluster["nodes"]
            assert node["alive"] and node["cpus"] == 2
            job_id = c.post("/jobs", json=tiny_spec(max_rounds=2).model_dump(mode="json")).json()["id"]
            job = wait_for(c, job_id, timeout=180)
            rounds = c.get(f"/jobs/{job_id}/history").json()["rounds"]
        assert job["status"] in ("STOPPED", "CONVERGED"), job["error"]
        assert {cand["node"] for r in rounds for cand in r["candidates"]} == {node["id"]}  # trained by Ray

        for second in ([NEUENH, "serve", "--port", "0", "--data-dir", str(tmp_path / "data")],
                       [NEUENH, "search", str(REPO / "examples" / "quickstart.yaml"), "--data-dir", str(tmp_path / "data")]):
            refused = subprocess.run(second, capture_output=True, text=True, cwd=REPO, env=clean_env(), timeout=60)
            assert refused.returncode == 2, refused.stderr
            [line] = refused.stderr.strip().splitlines()
            assert f"in use by neuenh serve (pid {server.proc.pid}" in line and "Traceback" not in refused.stderr

        ray_processes = server.children()
        assert ray_processes, "an embedded Ray runs child processes"
    finally:
        code = server.stop(signal.SIGTERM)
    assert code in (0, -signal.SIGTERM), server.output  # uvicorn re-raises the signal once shut down
    assert "Traceback" not in server.output
    deadline = time.monotonic() + 20
    while alive(ray_processes) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not alive(ray_processes), "Ray processes outlived the service"


def test_crash_mid_job_then_restart_resumes_and_loses_nothing(tmp_path):
    # Long enough that three rounds (~5 s on a quiet machine) follow the first commit: the tiny job
    # converges one round after its first commit, which a fast machine finishes between two polls.
    spec = tiny_spec(max_rounds=4, epochs_per_round=10).model_dump(mode="json")
    spec["data"][0]["samples"] = 4000
    first = ServeProcess(tmp_path / "data").wait_ready()
    try:
        with first.client() as c:
            job_id = c.post("/jobs", json=spec).json()["id"]
            wait_for(c, job_id, until=lambda j: j["last_round"] is not None or j["terminal"], timeout=180)
            before = c.get(f"/jobs/{job_id}/history").json()
    finally:
        first.stop(signal.SIGKILL)  # a crash: no shutdown, no chance to tidy up
    assert not before["terminal"], "the job ended before the crash; make it longer"

    second = ServeProcess(tmp_path / "data").wait_ready()  # the crashed owner's lock died with it
    try:
        with second.client() as c:
            job = wait_for(c, job_id, timeout=240)
            after = c.get(f"/jobs/{job_id}/history").json()
    finally:
        assert second.stop() in (0, -signal.SIGTERM), second.output
    assert job["status"] in ("STOPPED", "CONVERGED") and job["error"] is None, job
    assert f"resuming 1 unfinished job(s): {job_id}" in second.output
    rounds = after["rounds"]
    assert rounds[: len(before["rounds"])] == before["rounds"], "a committed round changed"
    assert [r["round"] for r in rounds] == list(range(len(rounds)))
    assert all(b["parent_state"] == a["winner_state"] for a, b in zip(rounds, rounds[1:]))
