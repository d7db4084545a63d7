"""The job routes end to end against a live server: submit, poll, history, model, idempotency,
cancel, list, errors."""

from __future__ import annotations

import io
import json
import zipfile

import httpx
import pytest

from neuenh.checkpoint import Bundle
from neuenh_service.storage import JobStatus
from jobspecs import fit_scored_spec, tiny_spec

from live_api import running_server, wait_for


def body(**search) -> dict:
    return tiny_spec(**search).model_dump(mode="json")


def _boom():
    raise RuntimeError("secret internals")


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    with running_server(tmp_path_factory.mktemp("api") / "data", max_request_bytes=20_000,
                        setup=lambda app: app.add_api_route("/v1/boom", _boom)) as s:
        yield s


@pytest.fixture(scope="module")
def finished(server):
    """One tiny job run to the end (2 rounds of 12 candidates)."""
    with server.client() as c:
        r = c.post("/jobs", json=body(max_rounds=2))
        assert r.status_code == 202, r.text
        submitted = r.json()
        return submitted, r.headers, wait_for(c, submitted["id"])


def test_submit_answers_202_with_links(finished):
    submitted, headers, _ = finished
    assert submitted["status"] == "QUEUED" and not submitted["terminal"]
    assert submitted["spec"]["search"]["max_rounds"] == 2
    job_url = f"/v1/jobs/{submitted['id']}"
    assert headers["location"] == job_url
    assert submitted["links"] == {"self": job_url, "history": job_url + "/history",
                                  "model": job_url + "/model", "cancel": job_url + "/cancel"}


def test_job_runs_to_the_end(finished):
    job = finished[2]
    assert job["status"] in ("STOPPED", "CONVERGED"), job["error"]
    assert job["last_round"] is not None and job["current_state"] is not None and job["progress"] is None


def test_history_has_every_candidate_and_the_winner(client, finished):
    job = finished[2]
    h = client.get(f"/jobs/{job['id']}/history").json()
    assert h["status"] == job["status"] and h["terminal"]
    assert [r["round"] for r in h["rounds"]] == list(range(job["last_round"] + 1))
    assert h["next_since_round"] == job["last_round"] + 1
    for r in h["rounds"]:
        assert len(r["candidates"]) == 12
        winners = [c for c in r["candidates"] if c["winner"]]
        assert [c["state"] for c in winners] == [r["winner_state"]]
        assert winners[0]["val_loss"] == r["winner_val_loss"]
        assert all(c["node"] == "inline" and c["epochs"] == 1 and c["wall_s"] > 0 for c in r["candidates"])
        assert all(c["val_loss"] is not None and c["train_loss"] is not None for c in r["candidates"] if c["ok"])
        assert r["finished_at"] >= r["started_at"]
    assert h["rounds"][-1]["winner_state"] == job["current_state"]
    stay0 = next(c for c in h["rounds"][0]["candidates"] if c["state"] == h["rounds"][0]["parent_state"])
    assert stay0["change"] == "stay" and h["start_val_loss"] == stay0["val_loss"]
    for r in h["rounds"]:
        assert r["kind"] == "search" and r["gain_over_start"] == pytest.approx(1 - r["winner_val_loss"] / stay0["val_loss"])
    assert h["gain_over_start"] == h["rounds"][-1]["gain_over_start"]
    later = client.get(f"/jobs/{job['id']}/history", params={"since_round": 1}).json()
    assert [r["round"] for r in later["rounds"]] == [r["round"] for r in h["rounds"][1:]]
    assert (later["start_val_loss"], later["gain_over_start"]) == (h["start_val_loss"], h["gain_over_start"])


def test_a_search_scored_by_fit_serves_both_losses(client, finished):
    """search.score: fit: every trained candidate's fit score is served beside its val loss, the
    winner is the lowest fit score; a job without held-out materials serves none."""
    h = client.get(f"/jobs/{finished[2]['id']}/history").json()
    assert h["score"] == "val" and all(r["winner_fit_score"] is None for r in h["rounds"])
    assert all(c["fit_score"] is None for r in h["rounds"] for c in r["candidates"])
    r = client.post("/jobs", json=fit_scored_spec(max_rounds=1).model_dump(mode="json"))
    assert r.status_code == 202, r.text
    job = wait_for(client, r.json()["id"])
    assert job["status"] in ("STOPPED", "CONVERGED"), job["error"]
    h = client.get(f"/jobs/{job['id']}/history").json()
    assert h["score"] == "fit"
    [round0] = h["rounds"]
    scored = [c for c in round0["candidates"] if c["ok"]]
    assert scored and all(c["fit_score"] is not None and c["val_loss"] is not None for c in scored)
    assert round0["winner_fit_score"] == min(c["fit_score"] for c in scored)
    assert next(c for c in scored if c["winner"])["fit_score"] == round0["winner_fit_score"]


def test_model_downloads_as_a_loadable_bundle(client, finished, tmp_path):
    job = finished[2]
    r = client.get(f"/jobs/{job['id']}/model")
    assert r.status_code == 200 and r.headers["content-type"] == "application/zip"
    assert r.headers["x-neuenh-state"] == job["current_state"]
    with zipfile.ZipFile(io.BytesIO(r.content)) as archive:
        assert sorted(archive.namelist()) == ["materials.safetensors", "model.json", "weights.safetensors"]
        archive.extractall(tmp_path / "model")
    bundle = Bundle.load(tmp_path / "model")
    assert bundle.model.state == job["current_state"]
    assert len(bundle.materials.names) == 2
    assert bundle.provenance["job"] == job["id"]


def test_idempotency_key_returns_the_same_job_and_cancel_stops_it(client):
    spec = body(epochs_per_round=20, max_rounds=20)
    first = client.post("/jobs", json=spec, headers={"Idempotency-Key": "k-1"})
    again = client.post("/jobs", json=spec, headers={"Idempotency-Key": "k-1"})
    assert (first.status_code, again.status_code) == (202, 200)
    assert again.json()["id"] == first.json()["id"]
    clash = client.post("/jobs", json=body(max_rounds=5), headers={"Idempotency-Key": "k-1"})
    assert clash.status_code == 409 and "k-1" in clash.json()["detail"]

    job_id = first.json()["id"]
    r = client.post(f"/jobs/{job_id}/cancel")
    assert r.status_code == 200 and r.json()["status"] == "CANCELLED"
    assert wait_for(client, job_id)["status"] == "CANCELLED"
    r = client.post(f"/jobs/{job_id}/cancel")
    assert r.status_code == 409 and "already CANCELLED" in r.json()["detail"]


def test_cancel_queued_job_and_model_before_round_0(server, client):
    job, _ = server.app.state.jobs.create_job(body())  # stored, never handed to the worker
    r = client.get(f"/jobs/{job.id}/model")
    assert r.status_code == 404 and "no committed round" in r.json()["detail"]
    assert client.post(f"/jobs/{job.id}/cancel").json()["status"] == "CANCELLED"
    assert client.get(f"/jobs/{job.id}").json()["status"] == "CANCELLED"


def test_list_pages_and_filters(client, finished):
    first = client.get("/jobs", params={"limit": 1}).json()
    assert len(first["jobs"]) == 1 and first["next_cursor"]
    rest = client.get("/jobs", params={"limit": 100, "cursor": first["next_cursor"]}).json()
    ids = [j["id"] for j in first["jobs"] + rest["jobs"]]
    assert len(ids) == len(set(ids)) and finished[0]["id"] in ids and rest["next_cursor"] is None
    status = finished[2]["status"]
    only = client.get("/jobs", params={"status": status}).json()["jobs"]
    assert only and all(j["status"] == status for j in only)
    both = client.get("/jobs", params=[("status", status), ("status", "CANCELLED")]).json()["jobs"]
    assert {j["status"] for j in both} <= {status, "CANCELLED"}


@pytest.mark.parametrize("path", ["", "/history", "/model"])
def test_unknown_job_is_404(client, path):
    r = client.get(f"/jobs/no-such-job{path}")
    assert r.status_code == 404 and "no-such-job" in r.json()["detail"]


def test_cancel_unknown_job_is_404(client):
    assert client.post("/jobs/no-such-job/cancel").status_code == 404


@pytest.mark.parametrize("change, field", [
    (lambda b: b.update(data=[]), "data"),
    (lambda b: b["search"].update(radius="wide"), "search.radius"),
    (lambda b: b["search"].update(epochs_per_round=0), "search.epochs_per_round"),
    (lambda b: b.update(colour="red"), "colour"),
    (lambda b: b.update(model="no-such-model"), "unknown model"),
    (lambda b: b["search"].update(radius=2), "search.radius"),                # 67 candidates > 64
    (lambda b: b["search"].update(epochs_per_round=5000), "search.epochs_per_round"),  # > max_epochs
    (lambda b: b["data"][0].update(samples=10**7), "data.0.samples"),          # > max_samples
    (lambda b: b["data"][0].update(materials=10**5, samples=10**3), "NEUENH_MAX_TOTAL_SAMPLES"),
    (lambda b: b.update(latent_dim=10**7), "NEUENH_MAX_LATENT_DIM"),
    (lambda b: b.update(module={"hidden": [16, 10**6]}), "NEUENH_MAX_MODULE_WIDTH"),
    (lambda b: b.update(module={"hidden": [16, 0]}), "module.hidden"),
    # issue 17, case 3: within every other limit, these exhausted memory or blocked the queue
    (lambda b: b["data"][0].update(materials=10**6, samples=20), "NEUENH_MAX_MATERIALS"),
    (lambda b: b.update(module={"hidden": [8] * 1_000}), "NEUENH_MAX_MODULE_DEPTH"),
    (lambda b: b.update(module={"hidden": [1024] * 16}), "NEUENH_MAX_MODULE_WEIGHTS"),
    (lambda b: b.update(data=[{"source": "rgl", "paths": ["a\x00b.bsdf"]}]), "not a usable path"),
])
def test_invalid_spec_is_422_naming_the_field(client, change, field):
    b = body()
    change(b)
    r = client.post("/jobs", json=b)
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert isinstance(detail, str) and field in detail


@pytest.mark.parametrize("path, params, words", [
    ("/jobs", {"limit": 0}, ["limit"]),
    ("/jobs", {"status": "DONE"}, ["status"]),
    ("/jobs", {"cursor": "x"}, ["cursor"]),
    ("/jobs", {"page": 2}, ["unknown query parameter(s) page", "cursor, limit, status"]),
    ("/jobs/any/history", {"since": 3}, ["unknown query parameter(s) since", "since_round"]),
])
def test_bad_query_is_422_naming_it(client, path, params, words):
    r = client.get(path, params=params)
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert isinstance(detail, str) and all(w in detail for w in words), detail


def test_405_allows_every_method_of_the_path(client):
    r = client.delete("/jobs")
    assert r.status_code == 405 and r.headers["allow"] == "GET, POST"


def test_malformed_json_is_422(client):
    r = client.post("/jobs", content=b"{not json", headers={"content-type": "application/json"})
    assert r.status_code == 422 and "JSON" in r.json()["detail"]


def test_oversized_body_is_413(client):
    r = client.post("/jobs", content=b"[" + b"0," * 20_000 + b"0]", headers={"content-type": "application/json"})
    assert r.status_code == 413 and "bytes" in r.json()["detail"]

    def chunks():
        for _ in range(30):
            yield b" " * 1000

    r = client.post("/jobs", content=chunks(), headers={"content-type": "application/json"})
    assert r.status_code == 413


def test_unexpected_error_is_500_without_internals(client):
    r = client.get("/boom")
    assert r.status_code == 500
    assert r.json() == {"detail": "internal server error; see the service log"}


def test_health_and_openapi(client, server):
    assert client.get("/health").json() == {"status": "ok", "version": "0.1.0", "worker_alive": True, "auth": False,
                                            "broken_jobs": {}}
    spec = httpx.get(server.url + "/openapi.json").json()
    assert "JobCreate" in spec["components"]["schemas"] and "/v1/jobs/{job_id}/history" in spec["paths"]


def test_store_records_match(server, finished):
    job = server.app.state.jobs.get_job(finished[0]["id"])
    assert job.status in (JobStatus.STOPPED, JobStatus.CONVERGED)


@pytest.mark.parametrize(
    "path",
    ["../shared/data/rgl/chm_orange_rgb.bsdf", "/etc/passwd", "ROOT/../outside.bsdf"],
    ids=["relative-outside", "absolute", "dotdot-escape"],
)
def test_file_sources_are_confined_to_the_data_roots(tmp_path, path):
    from neuenh_service.api.limits import outside_data_roots
    from neuenh_service.api.settings import Settings
    from neuenh_service.orchestrator.spec import parse_spec

    root = tmp_path / "root"
    root.mkdir()
    spec = parse_spec({"data": [{"source": "rgl", "paths": [path.replace("ROOT", str(root))]}]})
    problems = outside_data_roots(spec, Settings(data_dir=tmp_path, data_roots=[root]))
    assert len(problems) == 1 and "outside the data roots" in problems[0]
    inside = parse_spec({"data": [{"source": "rgl", "paths": [str(root / "a.bsdf")]}]})
    assert outside_data_roots(inside, Settings(data_dir=tmp_path, data_roots=[root])) == []
    assert outside_data_roots(inside, Settings(data_dir=tmp_path)) != []  # no roots: refused


@pytest.mark.parametrize("name,reasons", [("x" * 300 + ".bsdf", ["File name too long"]),
                                          ("a.bsdf/b.bsdf", ["Not a directory"]),
                                          # Python 3.11 raises "Symlink loop", later ones ELOOP's message
                                          ("loop/b.bsdf", ["Symlink loop", "Too many levels of symbolic links"])],
                         ids=["too-long", "under-a-file", "link-loop"])
def test_names_no_file_system_holds_are_refused_at_submission_inside_the_roots(tmp_path, name, reasons):
    """They used to be accepted, then fail the job with an OSError traceback in the service's log (a link loop:
    Python 3.11's RuntimeError, a 500)."""
    from neuenh_service.api.limits import outside_data_roots
    from neuenh_service.api.settings import Settings
    from neuenh_service.orchestrator.spec import parse_spec

    root = tmp_path / "root"
    root.mkdir()
    (root / "a.bsdf").write_bytes(b"")
    (root / "loop").symlink_to(root / "loop")
    settings = Settings(data_dir=tmp_path, data_roots=[root])
    spec = parse_spec({"data": [{"source": "rgl", "paths": [str(root / name), str(root / "missing.bsdf")]}]})
    [problem] = outside_data_roots(spec, settings)  # a missing file is named when the job reads it
    assert problem.startswith("data.0: ") and "is not a usable path" in problem, problem
    assert any(reason in problem for reason in reasons), problem


@pytest.mark.parametrize("host,token,ok", [("127.0.0.1", None, True), ("0.0.0.0", None, False),
                                            ("0.0.0.0", "s3cret", True), ("::1", None, True)])
def test_no_token_no_network_listening(host, token, ok):
    from neuenh_service.api.settings import Settings, check_listen_address

    settings = Settings(host=host, api_token=token)
    if ok:
        check_listen_address(settings)
    else:
        with pytest.raises(ValueError, match="without NEUENH_API_TOKEN"):
            check_listen_address(settings)


def test_the_dashboard_ignores_query_strings(server):
    r = httpx.get(server.url + "/", params={"utm_source": "mail"})
    assert r.status_code == 200 and "text/html" in r.headers["content-type"]


@pytest.mark.parametrize("fmt, suffix", [("glsl", ".glsl"), ("onnx", ".onnx")])
def test_export_zips_the_models_materials_in_a_renderers_format(client, finished, fmt, suffix):
    job = finished[2]
    model = client.get(f"/jobs/{job['id']}/model")
    with zipfile.ZipFile(io.BytesIO(model.content)) as archive:
        names = json.loads(archive.read("model.json"))["materials"]
    r = client.get(f"/jobs/{job['id']}/export", params={"format": fmt, "material": names[:1]})
    assert r.status_code == 200 and r.headers["content-type"] == "application/zip", r.text
    with zipfile.ZipFile(io.BytesIO(r.content)) as archive:
        files = archive.namelist()
        assert any(f.endswith(suffix) for f in files)
        if fmt == "glsl":
            assert "vec3 neuenh_brdf(vec3 wi, vec3 wo)" in archive.read(files[0]).decode()
    bad = client.get(f"/jobs/{job['id']}/export", params={"format": fmt, "material": ["nope"]})
    assert bad.status_code == 422 and "holds no material 'nope'" in bad.json()["detail"]
    assert client.get(f"/jobs/{job['id']}/export", params={"format": "renderman"}).status_code == 422
