"""Named tokens with roles (issue 17): admin, submit and read, from NEUENH_TOKENS_FILE (hashed),
tested as a matrix of role x route; NEUENH_API_TOKEN stays a single admin; SIGHUP re-reads the file."""

from __future__ import annotations

import signal
import time

import httpx
import pytest

from jobspecs import tiny_spec
from live_api import running_server, wait_for
from named_tokens import TOKENS, as_, write_tokens
from serve_process import ServeProcess

@pytest.fixture(scope="module")
def server(tmp_path_factory):
    root = tmp_path_factory.mktemp("roles")
    write_tokens(root / "tokens.json", TOKENS)
    with running_server(root / "data", tokens_file=root / "tokens.json", api_token="t-legacy",
                        data_roots=[root]) as s:
        with s.client() as c:
            s.jobs = {owner: c.post("/jobs", json=tiny_spec(max_rounds=1).model_dump(mode="json"),
                                    headers=as_(owner)).json()["id"] for owner in ("alice", "bob")}
            s.plans = {owner: c.post("/plans", json=scene_of(root), headers=as_(owner)).json()["id"]
                       for owner in ("alice", "bob")}
        with s.client(headers=as_("ops")) as c:
            for job_id in s.jobs.values():
                wait_for(c, job_id)
            for plan_id in s.plans.values():  # they fail: their file is missing
                wait_for(c, plan_id, kind="plans")
        yield s


def scene_of(root) -> dict:
    """A scene the service accepts (its file lies under the data roots) and then fails to plan."""
    return {"materials": [{"path": str(root / "missing.npz")}], "ladder": ["ggx"], "tolerance": {"relative": 0.1}}


# (route, whose job) -> expected status per caller; "own" is alice's job (or plan), "other" bob's.
MATRIX = [
    ("GET", "/jobs/{own}", {"ops": 200, "alice": 200, "wall": 200, "bob": 404}),
    ("GET", "/jobs/{own}/history", {"ops": 200, "alice": 200, "wall": 200, "bob": 404}),
    ("GET", "/jobs/{own}/model", {"ops": 200, "alice": 200, "wall": 200, "bob": 404}),
    ("POST", "/jobs/{own}/cancel", {"wall": 403, "bob": 404, "alice": 409, "ops": 409}),  # 409: already finished
    ("POST", "/jobs/{own}/fit", {"wall": 403, "bob": 404, "alice": 422, "ops": 422}),  # 422: no files sent
    ("GET", "/cluster", {"ops": 200, "alice": 200, "wall": 200, "bob": 200}),
    ("POST", "/jobs", {"wall": 403}),
    ("GET", "/plans/{own_plan}", {"ops": 200, "alice": 200, "wall": 200, "bob": 404}),
    ("GET", "/plans/{own_plan}/files/plan.md", {"bob": 404, "wall": 404, "alice": 404}),  # 404: not DONE
    ("POST", "/plans/{own_plan}/cancel", {"wall": 403, "bob": 404, "alice": 409, "ops": 409}),  # 409: it ended
    ("POST", "/plans", {"wall": 403}),
    ("POST", "/plan-uploads", {"wall": 403, "alice": 422}),  # 422: no files sent
]


@pytest.mark.parametrize("method, path, expected", MATRIX, ids=[f"{m} {p}" for m, p, _ in MATRIX])
def test_role_matrix(server, method, path, expected):
    with server.client() as c:
        for caller, code in expected.items():
            url = path.format(own=server.jobs["alice"], own_plan=server.plans["alice"])
            body = ({"json": tiny_spec().model_dump(mode="json")} if path == "/jobs"
                    else {"json": scene_of(server.settings.data_roots[0])} if path == "/plans" else {})
            r = c.request(method, url, headers=as_(caller), **body)
            assert r.status_code == code, f"{caller} {method} {url}: {r.status_code} {r.text[:200]}"


def test_a_submitter_lists_its_own_jobs_and_others_list_all(server):
    with server.client() as c:
        listed = {name: {j["id"] for j in c.get("/jobs", headers=as_(name)).json()["jobs"]} for name in TOKENS}
    assert listed["alice"] == {server.jobs["alice"]} and listed["bob"] == {server.jobs["bob"]}
    assert listed["ops"] >= set(server.jobs.values()) and listed["wall"] == listed["ops"]
    with server.client() as c:
        plans = {name: {p["id"] for p in c.get("/plans", headers=as_(name)).json()["plans"]} for name in TOKENS}
    assert plans["alice"] == {server.plans["alice"]} and plans["ops"] == plans["wall"] == set(server.plans.values())


def test_the_legacy_token_is_an_admin_and_unknown_tokens_are_401(server):
    with server.client() as c:
        assert c.get(f"/jobs/{server.jobs['bob']}", headers={"Authorization": "Bearer t-legacy"}).status_code == 200
        assert c.get("/jobs", headers={"Authorization": "Bearer nope"}).status_code == 401
        assert c.get("/health").json()["auth"] is True


def test_sighup_rereads_the_tokens_file(tmp_path):
    """A token added to the file works after SIGHUP, one removed stops working; a file that does
    not parse keeps the tokens in force."""
    tokens = tmp_path / "tokens.json"
    write_tokens(tokens, {"old": ("read", "t-old")})
    server = ServeProcess(tmp_path / "data", env={"NEUENH_TOKENS_FILE": str(tokens)}).wait_ready()
    try:

        def status(token):
            return httpx.get(server.url + "/v1/jobs", headers={"Authorization": f"Bearer {token}"}).status_code

        assert (status("t-old"), status("t-new")) == (200, 401)
        write_tokens(tokens, {"new": ("read", "t-new")})
        server.proc.send_signal(signal.SIGHUP)
        deadline = time.monotonic() + 10
        while status("t-new") != 200:
            assert time.monotonic() < deadline, server.output
            time.sleep(0.1)
        assert status("t-old") == 401
        tokens.write_text("{not json")
        server.proc.send_signal(signal.SIGHUP)
        time.sleep(0.5)
        assert status("t-new") == 200 and server.proc.poll() is None
    finally:
        server.stop()


@pytest.mark.parametrize("content, words", [
    ("[{]", ["not JSON"]),
    ('[{"name": "a", "role": "owner", "sha256": "' + "0" * 64 + '"}]', ["role 'owner'"]),
    ('[{"name": "a", "role": "read", "sha256": "abc"}]', ["sha256 must be"]),
])
def test_a_bad_tokens_file_is_one_line_at_start(tmp_path, capsys, monkeypatch, content, words):
    from neuenh_service.cli.main import main

    (tmp_path / "tokens.json").write_text(content)
    monkeypatch.setenv("NEUENH_TOKENS_FILE", str(tmp_path / "tokens.json"))
    code = main(["serve", "--port", "0", "--data-dir", str(tmp_path / "data")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and all(w in err[0] for w in words), err
