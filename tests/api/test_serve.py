"""``neuenh serve`` end to end with real parts: uvicorn on loopback, an embedded Ray training the
candidates, SQLite. One owner per store; SIGTERM shuts Ray down and leaves nothing running. (A crash
mid-job and the restart: ``test_shared_cluster.py``.)"""

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
