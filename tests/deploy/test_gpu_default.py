"""NEUENH_DEFAULT_GPUS_PER_CANDIDATE (set by the compose file's GPU setup): a job that does not say
how many GPUs a candidate takes gets the service's default, written into its stored spec; a job
that says so keeps its own."""

from jobspecs import tiny_spec
from live_api import running_server


def test_the_default_fills_only_an_unset_gpus_per_candidate(tmp_path):
    implicit = tiny_spec(max_rounds=1).model_dump(mode="json", exclude={"resources"})
    explicit = {**implicit, "resources": {"gpus_per_candidate": 0.0}}
    # autoscaling: this machine has no GPU, and the GPU nodes of a real deploy may not have joined yet
    with running_server(tmp_path / "data", default_gpus_per_candidate=0.25, autoscaling=True) as server, \
            server.client() as c:
        filled = c.post("/jobs", json=implicit).json()
        kept = c.post("/jobs", json=explicit).json()
        again = c.post("/jobs", json=implicit, headers={"Idempotency-Key": "k"}).json()
        same = c.post("/jobs", json=implicit, headers={"Idempotency-Key": "k"})
    assert filled["spec"]["resources"]["gpus_per_candidate"] == 0.25
    assert kept["spec"]["resources"]["gpus_per_candidate"] == 0.0
    assert same.status_code == 200 and same.json()["id"] == again["id"]  # a repeat is the same job
