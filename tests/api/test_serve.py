"""``neuenh serve`` end to end with real parts: uvicorn on loopback, an embedded Ray training the
candidates, SQLite. One owner per store; SIGTERM shuts Ray down and leaves nothing running. (A crash
mid-job and the restart: ``test_shared_cluster.py``.)"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time


from cli_runs import run_probing_torch
from jobspecs import tiny_spec
from live_api import wait_for
from serve_process import NEUENH, REPO, ServeProcess, clean_env


def alive(pids: set[int]) -> set[int]:
    return {pid for pid in pids if os.path.exists(f"/proc/{pid}") and
            open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()[0] != "Z"}


GRACE_S = 20  # NEUENH_SHUTDOWN_GRACE_S: a shutdown that waited on a running plan would take all of it


def test_serve_runs_jobs_on_ray_owns_its_store_and_shuts_down_cleanly(tmp_path):
    """Also issue 26, case 2: SIGTERM with a runaway plan running took 33 s (the grace ran out on the
    plan's thread) and left Ray's agents running; the plan's process is ended at once now."""
    from scene_files import runaway, write_tables

    (tmp_path / "tables").mkdir()
    tables = write_tables(tmp_path / "tables")
    server = ServeProcess(tmp_path / "data", env={"NEUENH_DATA_ROOTS": json.dumps([str(tables)]),
                                                  "NEUENH_SHUTDOWN_GRACE_S": str(GRACE_S)}).wait_ready()
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

        refused_serve, imported_torch = run_probing_torch("neuenh_service.cli.main", "serve", "--port", "0",
                                                          "--data-dir", tmp_path / "data", cwd=REPO, env=clean_env())
        assert not imported_torch, "serve refuses an owned store before importing the app"
        refused_search = subprocess.run([NEUENH, "search", str(REPO / "examples" / "quickstart.yaml"), "--data-dir",
                                         str(tmp_path / "data")], capture_output=True, text=True, cwd=REPO,
                                        env=clean_env(), timeout=60)
        for refused in (refused_serve, refused_search):
            assert refused.returncode == 2, refused.stderr
            [line] = refused.stderr.strip().splitlines()
            assert f"in use by neuenh serve (pid {server.proc.pid}" in line and "Traceback" not in refused.stderr

        with server.client() as c:
            plan_id = c.post("/plans", json=runaway(tables)).json()["id"]
            wait_for(c, plan_id, until=lambda plan: plan["status"] == "RUNNING", timeout=120, kind="plans")

        ray_processes = server.children()  # and the plan's process
        assert ray_processes, "an embedded Ray runs child processes"
    finally:
        started = time.monotonic()
        code = server.stop(signal.SIGTERM)
    assert time.monotonic() - started < GRACE_S, server.output  # nothing waited out the grace
    assert code in (0, -signal.SIGTERM), server.output  # uvicorn re-raises the signal once shut down
    assert "Traceback" not in server.output
    deadline = time.monotonic() + 20
    while alive(ray_processes) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not alive(ray_processes), "Ray processes (or the plan's) outlived the service"


def test_a_data_directory_that_is_a_file_is_one_line_before_the_app(tmp_path):
    taken = tmp_path / "data"
    taken.write_text("not a folder")
    run, imported_torch = run_probing_torch("neuenh_service.cli.main", "serve", "--port", "0", "--data-dir", taken,
                                            cwd=REPO, env=clean_env())
    assert run.returncode == 2 and "Traceback" not in run.stderr and not imported_torch, run.stderr
    [line] = run.stderr.strip().splitlines()
    assert line == f"neuenh serve: error: data directory {taken} (--data-dir, NEUENH_DATA_DIR) exists and is not a folder"
    assert taken.read_text() == "not a folder"
