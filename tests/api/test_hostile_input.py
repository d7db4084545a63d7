"""Attacks on the service's inputs, each reproduced and kept fixed (issue 17): text that is not
Unicode, seeds beyond 64 bits, specs whose memory the service cannot hold."""

from __future__ import annotations

import json

import pytest

from neuenh_service.storage import JobStatus
from neuenh_service.storage.sqlite import SQLiteJobStore
from jobspecs import tiny_spec

from live_api import running_server


def raw_json_with_lone_surrogate() -> bytes:
    """A spec whose name is the JSON escape of a lone surrogate (json.dumps writes it as \\ud800)."""
    spec = tiny_spec().model_dump(mode="json")
    spec["name"] = "\ud800"
    return json.dumps(spec).encode("ascii")


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    data = tmp_path_factory.mktemp("hostile") / "data"
    # A store written before specs were checked, holding a job whose name is a lone surrogate.
    with SQLiteJobStore(data / "jobs.sqlite") as store:
        spec = tiny_spec().model_dump(mode="json")
        spec["name"] = "poison \udc80"
        job, _ = store.create_job(spec)
        store.set_status(job.id, JobStatus.CANCELLED)
    with running_server(data) as s:
        s.poisoned = job.id
        yield s


def test_a_lone_surrogate_in_a_spec_is_refused_at_the_edge(server):
    with server.client() as c:
        r = c.post("/jobs", content=raw_json_with_lone_surrogate(), headers={"Content-Type": "application/json"})
        assert r.status_code == 422, r.text
        assert "name" in r.json()["detail"] and "surrogate" in r.json()["detail"]
        assert all(job["name"] != "\ud800" for job in c.get("/jobs").json()["jobs"])


def test_a_store_holding_a_lone_surrogate_still_lists_shows_and_cancels(server):
    with server.client() as c:
        listed = c.get("/jobs")
        assert listed.status_code == 200, listed.text
        [job] = [j for j in listed.json()["jobs"] if j["id"] == server.poisoned]
        assert job["name"] == "poison \ufffd" and job["spec"]["name"] == "poison \ufffd"
        assert c.get(f"/jobs/{server.poisoned}").status_code == 200
        assert c.post(f"/jobs/{server.poisoned}/cancel").status_code in (200, 409)


def test_a_seed_beyond_64_bits_is_refused_at_submission(server):
    """It was accepted, then failed at run time with "Overflow when unpacking long long"."""
    for where in ("train", "data"):
        spec = tiny_spec().model_dump(mode="json")
        if where == "train":
            spec["train"]["seed"] = 2**70
        else:
            spec["data"][0]["seed"] = 2**70
        with server.client() as c:
            r = c.post("/jobs", json=spec)
        assert r.status_code == 422, r.text
        assert "seed" in r.json()["detail"]


def test_a_spec_whose_estimated_memory_exceeds_the_limit_is_refused():
    """Within every count limit, a job can still need more memory than the service has
    (issue 17, case 3): its estimate is checked at submission."""
    from fastapi import HTTPException

    from neuenh_service.api.limits import BYTES_PER_MATERIAL, BYTES_PER_SAMPLE, check_limits, estimated_bytes
    from neuenh_service.api.settings import Settings

    spec = tiny_spec()
    spec.data[0] = spec.data[0].model_copy(update={"materials": 1_000, "samples": 5_000})
    assert estimated_bytes(spec) == 1_000 * 5_000 * BYTES_PER_SAMPLE + 1_000 * BYTES_PER_MATERIAL
    check_limits(spec, Settings(max_job_memory_bytes=estimated_bytes(spec)))  # at the limit: accepted
    with pytest.raises(HTTPException) as refused:
        check_limits(spec, Settings(max_job_memory_bytes=estimated_bytes(spec) - 1))
    assert refused.value.status_code == 422 and "NEUENH_MAX_JOB_MEMORY_BYTES" in refused.value.detail


def flip_a_byte(path) -> None:
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x01
    path.write_bytes(bytes(data))


def test_corrupted_artifacts_are_named_never_used(server):
    """Flipped bytes in a round checkpoint were served by GET /model and resumed from; flipped
    bytes in a cached dataset changed a job's final state (issue 17, case 5)."""
    from live_api import wait_for

    artifacts = server.settings.data_dir / "artifacts"
    with server.client() as c:
        job = c.post("/jobs", json=tiny_spec(max_rounds=1).model_dump(mode="json")).json()
        wait_for(c, job["id"])
        history = c.get(f"/jobs/{job['id']}/history").json()
        assert c.get(f"/jobs/{job['id']}/model").status_code == 200
        checkpoints = [p for p in artifacts.rglob("*") if p.is_file() and p.parent.parent.name == "sha256"]
        assert checkpoints and history["rounds"]
        for path in checkpoints:  # every content-addressed artifact: the checkpoints and the dataset
            flip_a_byte(path)
        r = c.get(f"/jobs/{job['id']}/model")
        assert r.status_code == 507 and "is corrupt" in r.json()["detail"] and "sha256/" in r.json()["detail"]
        # the same recipe again: its cached dataset is corrupt, so the job fails naming it
        again = c.post("/jobs", json=tiny_spec(max_rounds=1).model_dump(mode="json"),
                       headers={"Idempotency-Key": "again"}).json()
        failed = wait_for(c, again["id"])
        assert failed["status"] == "FAILED" and "is corrupt" in failed["error"]


@pytest.mark.parametrize("resources, words", [
    ({"cpus_per_candidate": 64}, ["cpus_per_candidate: 64", "no candidate could ever start"]),
    ({"gpus_per_candidate": 1}, ["gpus_per_candidate: 1", "0 GPUs"]),
])
def test_resources_no_node_has_are_refused_at_submission(server, resources, words):
    """cpus_per_candidate: 2 on a 1-CPU cluster was accepted, then RUNNING 0/3 for minutes with
    every later job behind it (issue 17, case 6)."""
    spec = tiny_spec().model_dump(mode="json")
    spec["resources"].update(resources)
    with server.client() as c:
        r = c.post("/jobs", json=spec)
    assert r.status_code == 422 and all(w in r.json()["detail"] for w in words), r.text


@pytest.mark.parametrize("host, code", [
    ("127.0.0.1", 200), ("localhost:8000", 200), ("[::1]:8000", 200),
    ("attacker.example", 421), ("attacker.example:8000", 421), ("localhost.example", 421),
])
def test_a_token_less_service_answers_loopback_host_names_only(server, host, code):
    """A DNS-rebinding page reaches a token-less loopback service under its own name: refused
    (issue 17, case 14). The service listens on loopback without a token (case 13 checks that by
    the resolved addresses: ``localhost.example`` is not loopback)."""
    from neuenh_service.api.settings import is_loopback

    with server.client() as c:
        r = c.get("/jobs", headers={"Host": host})
    assert r.status_code == code, r.text
    assert not is_loopback("localhost.example") and is_loopback("localhost") and is_loopback("::1")
