"""Attacks on the service's inputs, each reproduced and kept fixed (issue 17): text that is not
Unicode, and uploads that inflate on reading."""

from __future__ import annotations

import json

import pytest

from storage import JobStatus
from storage.sqlite import SQLiteJobStore
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
