"""``POST /v1/jobs/{id}/fit`` and ``GET /v1/cluster`` against a live server.

The fit is checked against an independent reference: measurements generated from plain GGX with
known parameters, fitted with the model of a job whose every position is fixed to the analytical
term, must give those parameters back."""

from __future__ import annotations

import io

import numpy as np
import pytest
import torch

from data_files import nbrdf_weights, tiny_rgl_fields, write_tensor_file
from jobspecs import tiny_spec
from live_api import running_server, wait_for
from neuenh.data.directions import sample_directions
from neuenh.data.measured import load_measured
from neuenh.data.table import write_table
from neuenh.models import get_model
from neuenh.study.heldout import draw_fit_test

TRUTH = {"normal": [0.0, 0.0], "t_theta": [0.0], "rho_d": [0.30, 0.20, 0.10], "rho_s": [0.8, 0.8, 0.8],
         "alpha_x": [0.15], "alpha_y": [0.15], "f0": [0.5]}


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    with running_server(tmp_path_factory.mktemp("fit") / "data", max_samples=5000, max_epochs=400,
                        max_upload_bytes=400_000) as s:
        yield s


@pytest.fixture(scope="module")
def client(server):  # module-wide: the plain job fixture uses it
    with server.client() as c:
        yield c


@pytest.fixture(scope="module")
def plain_job(client):
    """A job that can only keep plain GGX: every position fixed to its analytical term."""
    spec = tiny_spec(max_rounds=1, fixed={p: 0 for p in get_model("ggx").positions}).model_dump(mode="json")
    job_id = client.post("/jobs", json=spec).json()["id"]
    job = wait_for(client, job_id)
    assert job["current_state"] == "0" * 11, job
    return job


def ggx_table(path, n=3000, seed=0, params=TRUTH):
    wi, wo = sample_directions(n, seed=seed, dtype=torch.float32)
    f_r = get_model("ggx").evaluate(wi, wo, {k: torch.tensor(v) for k, v in params.items()})
    return write_table(path, wi, wo, f_r.detach())


def upload(*paths, **form):
    return {"files": [("files", (p.name, p.read_bytes())) for p in paths], "data": form}


def test_fit_recovers_the_parameters_of_known_measurements(client, plain_job, tmp_path):
    table = ggx_table(tmp_path / "brushed.npz")
    r = client.post(f"/jobs/{plain_job['id']}/fit", **upload(table, epochs="300"))
    assert r.status_code == 200, r.text
    fit = r.json()
    assert (fit["job_id"], fit["round"], fit["state"]) == (plain_job["id"], plain_job["last_round"], "0" * 11)
    # a plain model's fast fit: L-BFGS, the epochs its iterations per phase
    assert (fit["protocol"]["name"], fit["protocol"]["iterations"]) == ("plain", 300)
    [material] = fit["materials"]
    assert material["name"] == "brushed" and material["samples"] == 3000
    assert material["loss"] < 5e-3
    p = material["params"]
    assert material["latent"] is None and material["capacity"] == "analytical"  # plain GGX reads no latent code
    assert material["params_per_material"] == 12 and material["corrections"] == {}
    np.testing.assert_allclose(p["rho_d"], TRUTH["rho_d"], atol=0.02)
    np.testing.assert_allclose([p["alpha_x"][0], p["alpha_y"][0]], [0.15, 0.15], rtol=0.15)


def test_fit_takes_several_materials_and_csv(client, plain_job, tmp_path):
    rough = {**TRUTH, "alpha_x": [0.5], "alpha_y": [0.5]}
    paths = [ggx_table(tmp_path / "glossy.npz", n=1000), ggx_table(tmp_path / "rough.csv", n=1000, params=rough)]
    fit = client.post(f"/jobs/{plain_job['id']}/fit", **upload(*paths, epochs="200")).json()
    assert [m["name"] for m in fit["materials"]] == ["glossy", "rough"]
    glossy, rough_fit = (m["params"]["alpha_x"][0] for m in fit["materials"])
    assert glossy < 0.3 < rough_fit


def test_fit_draws_pairs_from_an_rgl_file_as_neuenh_fit_does(client, plain_job, tmp_path):
    """An RGL upload is drawn on the service as ``neuenh fit`` and ``neuenh-client fit`` draw it
    (``draw_fit_test``): the answer is the very fit of the table of those pairs, drawn here. The
    draw's size is checked against the service's limit only when something is drawn: a table's rows
    are its own (this server's limit is 5,000 pairs)."""
    rgl = write_tensor_file(tmp_path / "tiny.bsdf", tiny_rgl_fields())
    r = client.post(f"/jobs/{plain_job['id']}/fit", **upload(rgl, samples="400", near_mirror="0.25", seed="3",
                                                              epochs="60"))
    assert r.status_code == 200, r.text
    drawn = r.json()
    assert drawn["drawn"] == {"samples": 400, "near_mirror": 0.25, "seed": 3, "materials": ["tiny"]}
    assert [(m["name"], m["samples"]) for m in drawn["materials"]] == [("tiny", 400)]
    pairs, _, _ = draw_fit_test(load_measured(rgl, "tiny"), 400, 1, 3, 0.25)
    table = write_table(tmp_path / "tiny.npz", pairs.wi, pairs.wo, pairs.f_r)
    as_table = client.post(f"/jobs/{plain_job['id']}/fit", **upload(table, epochs="60")).json()
    assert as_table["drawn"] is None and as_table["materials"] == drawn["materials"]
    table_only = client.post(f"/jobs/{plain_job['id']}/fit", **upload(table, samples="5001", epochs="60"))
    assert table_only.status_code == 200 and table_only.json()["materials"] == drawn["materials"], table_only.text


@pytest.mark.parametrize("case, status, words", [
    ("not a table", 422, ["junk.npz"]),
    ("nbrdf weights", 422, ["weights.npz", "NBRDF network weights (a model, not measurements)", "uploads are measurement tables"]),
    ("truncated rgl", 422, ["broken.bsdf"]),
    ("too many drawn", 422, ["samples: 5001", "NEUENH_MAX_SAMPLES"]),
    ("near_mirror out of range", 422, ["near_mirror"]),
    ("same names", 422, ["share a material name"]),
    ("too many samples", 422, ["5000", "NEUENH_MAX_SAMPLES"]),
    ("too many epochs", 422, ["400", "NEUENH_MAX_EPOCHS"]),
    ("bad method", 422, ["method"]),
    ("no files", 422, ["files"]),
    ("too large", 413, ["NEUENH_MAX_UPLOAD_BYTES"]),
])
def test_fit_refuses_bad_uploads_naming_the_problem(client, plain_job, tmp_path, case, status, words):
    good = ggx_table(tmp_path / "good.npz", n=200)
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"PK\x03\x04 this is not an npz")
    weights = tmp_path / "weights.npz"
    np.savez(weights, **nbrdf_weights(["only"]))
    rgl = write_tensor_file(tmp_path / "tiny.bsdf", tiny_rgl_fields())
    request = {
        "not a table": upload(junk),
        "nbrdf weights": upload(weights),
        "truncated rgl": {"files": [("files", ("broken.bsdf", rgl.read_bytes()[: len(rgl.read_bytes()) // 2]))]},
        "too many drawn": upload(rgl, samples="5001"),
        "near_mirror out of range": upload(rgl, near_mirror="1.5"),
        "same names": upload(good, ggx_table(tmp_path / "good.csv", n=200)),
        "too many samples": upload(ggx_table(tmp_path / "big.npz", n=5001)),
        "too many epochs": upload(good, epochs="401"),
        "bad method": upload(good, method="newton"),
        "no files": {"data": {"method": "fast"}},
        "too large": {"files": [("files", ("huge.npz", io.BytesIO(b"0" * 500_000)))]},
    }[case]
    r = client.post(f"/jobs/{plain_job['id']}/fit", **request)
    assert r.status_code == status, r.text
    detail = r.json()["detail"]
    assert all(w in detail for w in words), detail
    assert "Traceback" not in r.text and str(tmp_path) not in detail


def test_fit_needs_a_committed_round(server, client, tmp_path):
    job, _ = server.app.state.jobs.create_job(tiny_spec().model_dump(mode="json"))  # never run
    r = client.post(f"/jobs/{job.id}/fit", **upload(ggx_table(tmp_path / "m.npz", n=100)))
    assert r.status_code == 404 and "no committed round" in r.json()["detail"]
    assert client.post("/jobs/nope/fit", **upload(tmp_path / "m.npz")).status_code == 404


def test_cluster_describes_the_inline_executor(client):
    c = client.get("/cluster").json()
    assert c["backend"] == "inline" and c["address"] is None
    [node] = c["nodes"]
    assert node["alive"] and node["cpus"] == c["cpus"] >= 1
    assert 0 <= c["busy_candidates"] <= 1 and c["cpus_available"] <= c["cpus"]
