"""The service with its artifacts in a bucket (``NEUENH_S3_*``): checkpoints and the cached dataset
land in the bucket, not in the data directory, and the model downloads from there. A missing
bucket or an unreachable endpoint stops ``neuenh serve`` before it starts (before it imports torch),
in one line."""

from __future__ import annotations

import socket

from cli_runs import run_probing_torch
from jobspecs import tiny_spec
from live_api import running_server, wait_for
from neuenh_service.orchestrator.dataset import dataset_key
from s3_server import CREDENTIALS
from serve_process import REPO, clean_env
from neuenh_service.storage import SQLiteJobStore

S3_SETTINGS = {"s3_access_key_id": CREDENTIALS["aws_access_key_id"],
               "s3_secret_access_key": CREDENTIALS["aws_secret_access_key"]}


def test_artifacts_live_in_the_bucket(tmp_path, s3_server):
    bucket = s3_server.create_bucket("service-artifacts")
    with running_server(tmp_path / "data", s3_bucket=bucket, s3_prefix="prod", s3_endpoint_url=s3_server.url,
                        **S3_SETTINGS) as server, server.client() as c:
        spec = tiny_spec(max_rounds=2)
        job_id = c.post("/jobs", json=spec.model_dump(mode="json")).json()["id"]
        job = wait_for(c, job_id, timeout=120)
        model = c.get(f"/jobs/{job_id}/model")
    assert job["status"] in ("STOPPED", "CONVERGED"), job["error"]
    assert model.status_code == 200 and model.content[:2] == b"PK"
    keys = [o["Key"] for o in s3_server.client().list_objects_v2(Bucket=bucket)["Contents"]]
    with SQLiteJobStore(tmp_path / "data" / "jobs.sqlite") as store:  # each round names its checkpoint
        checkpoints = {r.artifact_key for r in store.rounds(job_id)}
    assert len(checkpoints) == job["last_round"] + 1 and all(k.startswith("sha256/") for k in checkpoints)
    assert {f"prod/{k}" for k in checkpoints} <= set(keys)  # content-addressed, verified when read
    assert f"prod/{dataset_key(spec)}" in keys  # the cached dataset's index
    assert not (tmp_path / "data" / "artifacts").exists()  # nothing on the api's disk but the job store


def refused_serve(tmp_path, **env: str) -> str:
    """``neuenh serve``'s one line; it refuses before importing the app (torch, Ray)."""
    run, imported_torch = run_probing_torch("neuenh_service.cli.main", "serve", "--port", "0", "--data-dir",
                                            tmp_path / "data", cwd=REPO,
                                            env=clean_env(**{f"NEUENH_{k.upper()}": v for k, v in env.items()}))
    assert run.returncode == 2, run.stdout + run.stderr
    assert "Traceback" not in run.stderr and not imported_torch
    [line] = run.stderr.strip().splitlines()
    return line


def test_a_missing_bucket_is_one_line(tmp_path, s3_server):
    line = refused_serve(tmp_path, s3_bucket="not-created", s3_endpoint_url=s3_server.url, **S3_SETTINGS)
    assert line == f"neuenh serve: error: S3 bucket 'not-created' does not exist at {s3_server.url}"


def test_an_unreachable_endpoint_is_one_line(tmp_path):
    closed = socket.create_server(("127.0.0.1", 0))
    url = f"http://127.0.0.1:{closed.getsockname()[1]}"
    closed.close()
    line = refused_serve(tmp_path, s3_bucket="b", s3_endpoint_url=url, s3_max_attempts="1", **S3_SETTINGS)
    assert line == f"neuenh serve: error: cannot reach the S3 endpoint {url} for bucket 'b'"

