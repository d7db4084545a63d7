"""docker-compose.yml, exercised without Docker: its services' commands and environments run as
local processes (``compose_local``): a Ray head, two Ray worker nodes, the S3 server, the bucket's
one-shot and the api. A radius-2 job submitted with ``neuenh-client`` trains on both worker nodes,
its checkpoints land in the bucket, ``GET /v1/cluster`` lists the nodes; one worker node and the api
are killed mid-round: the restarted api reads back the candidates that had finished, the round
completes on the surviving node, nothing committed changes and the job ends where an
uninterrupted run does. Then the api plans a scene with every rung of the shipped enhanced-ggx.

The one service not run as written is the object store: the MinIO image is replaced by moto's S3
server (``moto_server``) on a loopback port; everything else is the compose file's own command."""

from __future__ import annotations

import secrets
import subprocess
import time
from pathlib import Path

import boto3
import httpx
import pytest
import yaml

from compose_local import InterpolationError, LocalCompose, interpolate
from jobspecs import run_alone_soon, served_path
from live_api import wait_plan
from neuenh.data.synthetic import synthetic_ggx
from neuenh.pretrained import rungs
from scene_files import write_material
from s3_server import MOTO_SERVER
from serve_process import REPO, clean_env
from neuenh_service.storage import SQLiteJobStore

COMPOSE = REPO / "docker-compose.yml"
NEUENH_CLIENT = str(Path(MOTO_SERVER).parent / "neuenh-client")
ENV = {  # what an operator puts in .env
    "RAY_AUTH_TOKEN": secrets.token_hex(16),
    "S3_SECRET_KEY": "compose-test-secret",
    "NEUENH_API_TOKEN": "compose-test-token",
    # two nodes of one CPU each: this machine has two cores
    "NEUENH_WORKER_CPUS": "1",
    "NEUENH_WORKER_OBJECT_STORE_BYTES": str(200 << 20),
    "NEUENH_API_OBJECT_STORE_BYTES": str(200 << 20),
}
SPEC = {
    # two rounds: the kill comes in round 1, after round 0 is committed. The five operators keep their
    # original digit, so the six terms give 1 + 6 + 15 = 22 candidates a round (67 with all eleven free):
    # enough for both nodes and for a kill mid-round, at a third of the cost.
    "search": {"radius": 2, "epochs_per_round": 3, "max_rounds": 2,
               "fixed": {op: 0 for op in ("S*D", "S*D*F", "S*D*F*G", "S*D*F*G*invE", "M+S*D*F*G*invE")}},
    "train": {"batch_size": 2000, "lr": 5.0e-3},
    "data": [{"source": "synthetic_zoo", "materials": 2, "samples": 1500, "seed": 1}],
}


def test_the_compose_file_says_what_the_deployment_needs():
    raw = yaml.safe_load(COMPOSE.read_text())
    services = interpolate(raw["services"], ENV)
    assert {"ray-head", "ray-worker", "ray-worker-gpu", "object-store", "create-bucket", "api"} <= set(services)
    images = {services[s]["image"] for s in ("ray-head", "ray-worker", "api", "create-bucket")}
    assert images == {"neuenh:latest"}, "one image, so Python and Ray match on every node"
    head = services["ray-head"]["command"]
    assert head[:3] == ["ray", "start", "--head"] and head[head.index("--num-cpus") + 1] == "0"
    for worker in ("ray-worker", "ray-worker-gpu"):
        w = services[worker]
        # Workers reach nothing but the Ray cluster: no volume, no bucket credentials. What they
        # train on comes through Ray's object store (RayExecutor passes references).
        assert "volumes" not in w and set(w["environment"]) == {"RAY_AUTH_MODE", "RAY_AUTH_TOKEN"}
        assert "shm_size" in w and "container_name" not in w and "ports" not in w  # scalable
    gpu = services["ray-worker-gpu"]
    assert gpu["profiles"] == ["gpu"] and gpu["deploy"]["resources"]["reservations"]["devices"][0]["capabilities"] == ["gpu"]
    api = services["api"]
    assert "neuenh serve" in api["command"][-1] and api["environment"]["RAY_ADDRESS"] == "ray-head:6379"
    assert api["volumes"] == ["jobs:/var/lib/neuenh"] and "healthcheck" in api
    assert api["depends_on"]["create-bucket"] == {"condition": "service_completed_successfully"}
    for name in ("NEUENH_API_TOKEN", "RAY_AUTH_TOKEN", "S3_SECRET_KEY"):  # refused when missing
        with pytest.raises(InterpolationError, match=name):
            interpolate(raw["services"], {k: v for k, v in ENV.items() if k != name})


@pytest.fixture
def stack():
    compose = LocalCompose(COMPOSE, ENV, {"ray-head": [6379], "object-store": [9000], "api": [8000]})
    try:
        yield compose
    finally:
        compose.close()


def plan_with_the_shipped_model(api: httpx.Client, where: Path) -> dict:
    """A scene sent with its measurements, planned on the api with every rung of the shipped
    enhanced-ggx: the image carries models/ as package data (tests/test_packaging.py checks its
    build context; here the api is this virtualenv's install, as the image's is its own)."""
    table = write_material(where / "gloss.npz", synthetic_ggx(1, seed=3, noise_sigma=0.0)[0], n=1200)
    scene = {"materials": [{"path": "gloss.npz"}], "ladder": [{"rungs": "enhanced-ggx"}],
             "tolerance": {"metric": "log_l1", "relative": 0.1},
             "fit": {"samples": 600, "test_samples": 600, "epochs": 20}}
    r = api.post("/plan-uploads", data={"scene": yaml.safe_dump(scene)},
                 files=[("files", ("gloss.npz", table.read_bytes()))])
    assert r.status_code == 202, r.text
    return wait_plan(api, r.json()["id"])


def test_the_stack_runs_a_radius_2_job_on_two_worker_nodes_and_survives_losing_one_and_the_api(stack):
    start = time.monotonic()
    reference = run_alone_soon(stack.root, [SPEC])
    stack.replace("object-store", [MOTO_SERVER, "-H", "127.0.0.1", "-p", str(stack.port("object-store", 9000))])
    stack.start("object-store")
    deadline = time.monotonic() + 30
    while True:  # the one-shot runs until the store answers, like its restart: on-failure
        made = stack.run("create-bucket")
        if made.returncode == 0 or time.monotonic() > deadline:
            break
        time.sleep(0.5)
    assert made.stdout.strip() == "bucket neuenh created", made.stderr
    assert stack.run("create-bucket").stdout.strip() == "bucket neuenh exists"  # idempotent

    stack.start("ray-head")
    stack.healthy("ray-head", timeout=60)
    for replica in (0, 1):  # --scale ray-worker=2; one after the other (2 cores)
        stack.start("ray-worker", replica)
        stack.wait_log(f"ray-worker-{replica}", "Ray runtime started", timeout=60)
    data_dir = stack.volume_dir("api", "/var/lib/neuenh")
    stack.start("api", paths={"/var/lib/neuenh": data_dir})
    stack.healthy("api", timeout=90)
    started = time.monotonic() - start

    url, token = stack.url("api", 8000), ENV["NEUENH_API_TOKEN"]
    with httpx.Client(base_url=url + "/v1", headers={"Authorization": f"Bearer {token}"}, timeout=30) as api:
        assert httpx.get(url + "/v1/cluster").status_code == 401  # the token is required
        cluster = api.get("/cluster").json()
        assert cluster["backend"] == "ray" and cluster["cpus"] == 2
        workers = sorted(n["id"] for n in cluster["nodes"] if n["alive"] and n["cpus"] == 1)
        assert len(workers) == 2 and len(cluster["nodes"]) == 4  # + the head and the api's node

        spec_file = stack.root / "job.yaml"
        spec_file.write_text(yaml.safe_dump(SPEC))
        client = subprocess.Popen([NEUENH_CLIENT, "submit", str(spec_file), "--wait"],
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                  env={**clean_env(), "NEUENH_URL": url, "NEUENH_API_TOKEN": token})
        try:
            job_id, before, killed_in = None, None, None
            deadline = time.monotonic() + 120
            while killed_in is None:  # kill ray-worker-1 mid-round once round 0 is committed
                assert time.monotonic() < deadline and client.poll() is None, client.communicate()
                jobs = api.get("/jobs").json()["jobs"]
                job = jobs[0] if jobs else None
                progress = job and job["progress"]
                if job and job["last_round"] == 0 and progress and progress["round"] == 1 \
                        and 5 <= progress["done"] < progress["total"]:
                    job_id, before = job["id"], api.get(f"/jobs/{job['id']}/history").json()
                    stack.kill_node("ray-worker-1")
                    killed_in = progress
                time.sleep(0.1)
            # ... and the api with it, mid-round: what had finished is in its store; the rest re-trains
            stack.kill_node("api-0")
            with SQLiteJobStore(data_dir / "jobs.sqlite") as store:
                held = {f.candidate.state for f in store.finished_candidates(job_id, 1)}
            finished = len(held)
            stack.start("api", paths={"/var/lib/neuenh": data_dir})
            stack.healthy("api", timeout=90)
            assert f"resuming 1 unfinished job(s): {job_id}" in stack.log("api-0")
            out, err = client.communicate(timeout=150)  # the client waited out the lost service
        finally:
            client.kill()
        assert client.returncode == 0, err
        assert out.strip() == job_id

        shipped = plan_with_the_shipped_model(api, stack.root)
        after = api.get(f"/jobs/{job_id}/history").json()
        job = api.get(f"/jobs/{job_id}").json()
        deadline = time.monotonic() + 60
        while True:  # Ray marks a node dead after its missed health checks
            nodes = {n["id"]: n["alive"] for n in api.get("/cluster").json()["nodes"]}
            if not all(nodes[w] for w in workers) or time.monotonic() > deadline:
                break
            time.sleep(1)

    assert shipped["status"] == "DONE", shipped["error"]
    tried = {r["rung"] for r in shipped["plan"]["materials"][0]["results"]}
    assert tried == {f"enhanced-ggx@{r.round}:{r.state}" for r in rungs("enhanced-ggx")}, tried
    assert job["status"] in ("STOPPED", "CONVERGED") and job["error"] is None, job
    assert after["rounds"][1]["recovered"] == finished >= 5
    assert served_path(after) == reference.result(timeout=300)[0], "not what an uninterrupted run reaches"
    rounds = after["rounds"]
    assert len(rounds) >= 2 and all(len(r["candidates"]) == 22 for r in rounds)  # 1 + 6 + 15
    assert all(c["error"] is None for r in rounds for c in r["candidates"]), "a candidate failed"
    assert {c["node"] for c in rounds[0]["candidates"]} == set(workers), "both worker nodes train"
    assert rounds[: len(before["rounds"])] == before["rounds"], "a committed round changed"
    assert [r["round"] for r in rounds] == list(range(len(rounds)))
    assert all(b["parent_state"] == a["winner_state"] for a, b in zip(rounds, rounds[1:]))
    killed = [w for w in workers if not nodes[w]]
    assert len(killed) == 1, nodes  # the killed node is listed dead, the other alive
    survivor = next(w for w in workers if w != killed[0])
    late = [c for c in rounds[1]["candidates"] if c["state"] not in held]
    assert late and all(c["node"] == survivor for c in late), "candidates trained after the kill ran on the survivor"

    bucket = boto3.client("s3", endpoint_url=stack.url("object-store", 9000), region_name="us-east-1",
                          aws_access_key_id="neuenh", aws_secret_access_key=ENV["S3_SECRET_KEY"])
    keys = {o["Key"] for o in bucket.list_objects_v2(Bucket="neuenh")["Contents"]}
    # every round's checkpoint and the dataset, content-addressed (sha256/<2>/<64>), in the bucket
    assert len([k for k in keys if k.startswith("sha256/")]) >= len(rounds) + 1
    assert not (data_dir / "artifacts").exists()  # the api keeps only the job store on its volume
    assert (data_dir / "jobs.sqlite").exists()
    print(f"stack up in {started:.0f} s; killed mid-round {killed_in['round']} at "
          f"{killed_in['done']}/{killed_in['total']} with the api, {finished} recovered; "
          f"total {time.monotonic() - start:.0f} s")
