"""``/v1/plans`` on a live server: a scene planned as a persisted job kind — queued, run, its files
served; the same plan resumed after a restart keeps the materials it had planned; scenes reading
files outside the data roots or naming nothing real are refused in one line."""

from __future__ import annotations

import time

import pytest

from scene_files import scene, write_tables
from storage import SQLitePlanStore


def wait_plan(c, plan_id: str, timeout: float = 180) -> dict:
    deadline = time.monotonic() + timeout
    while True:
        plan = c.get(f"/plans/{plan_id}").json()
        if plan["terminal"]:
            return plan
        assert time.monotonic() < deadline, plan
        time.sleep(0.2)


@pytest.fixture(scope="module")
def tables(tmp_path_factory):
    return write_tables(tmp_path_factory.mktemp("roots") / "")


def absolute(tables, **changes) -> dict:
    data = scene(tables, **changes)
    data["materials"] = [{**m, "path": str(tables / m["path"])} for m in data["materials"]]
    return data


def test_a_plan_runs_and_serves_its_files(live_server, tables):
    server = live_server(data_roots=[tables])
    with server.client() as c:
        r = c.post("/plans", json=absolute(tables))
        assert r.status_code == 202, r.text
        plan = wait_plan(c, r.json()["id"])
        assert plan["status"] == "DONE" and plan["materials_done"] == plan["materials_total"] == 2, plan["error"]
        chosen = {m["name"]: m["chosen"] for m in plan["plan"]["materials"]}
        assert chosen == {"gloss": "ggx", "retro": "nbrdf"}
        assert set(plan["files"]) == {"plan.json", "plan.md", "cost_vs_error.png"}  # no rung with modules: no bundles
        png = c.get(f"/plans/{plan['id']}/files/cost_vs_error.png")
        assert png.status_code == 200 and png.headers["content-type"] == "image/png" and png.content[:4] == b"\x89PNG"
        assert "| **the plan** |" in c.get(f"/plans/{plan['id']}/files/plan.md").text
        assert c.get(f"/plans/{plan['id']}/files/secrets.txt").status_code == 404
        assert [p["id"] for p in c.get("/plans").json()["plans"]] == [plan["id"]]


def test_a_plan_interrupted_by_a_restart_plans_only_the_rest(live_server, tables, tmp_path):
    data_dir = tmp_path / "data"
    three = absolute(tables, materials=[{"path": n} for n in ("gloss.npz", "retro.npz", "sheen.npz")])
    store = SQLitePlanStore(data_dir / "jobs.sqlite")
    plan, _ = store.create_plan(three)  # as the API stores it, then a crash after one material
    store.start(plan.id, 3)
    # a first material planned before the crash: a result no planner would produce, so it shows
    store.record_material(plan.id, "gloss", {"name": "gloss", "weight": 1.0, "chosen": "ggx", "results": [
        {"rung": "ggx", "error": 0.5, "heldout_log_l1": 0.5, "fit_loss": 0.5, "n_params": 12, "param_bytes": 48,
         "params": {}}, {"rung": "nbrdf", "error": 0.6, "heldout_log_l1": 0.6, "fit_loss": 0.6, "n_params": 675,
                         "param_bytes": 2700, "params": {}}]})
    store.close()
    server = live_server(data_roots=[tables])
    with server.client() as c:
        done = wait_plan(c, plan.id)
    assert done["status"] == "DONE", done["error"]
    by_name = {m["name"]: m for m in done["plan"]["materials"]}
    assert by_name["gloss"]["error"] == 0.5  # kept, not planned again
    assert by_name["retro"]["chosen"] == "nbrdf" and by_name["sheen"]["error"] < 0.5


@pytest.mark.parametrize("change, message", [
    (lambda t: {"materials": [{"path": "/etc/passwd"}]}, "materials.0: /etc/passwd is outside the data roots"),
    (lambda t: {"ladder": ["ggx", {"rungs": "/tmp"}]}, "ladder.1: /tmp is outside the data roots"),
    (lambda t: {"ladder": []}, "ladder: List should have at least 1 item"),
    (lambda t: {"tolerance": {"metric": "ssim"}}, "exactly one of 'relative'"),
], ids=["material-outside", "bundle-outside", "empty-ladder", "no-tolerance"])
def test_bad_scenes_are_refused_before_anything_is_stored(live_server, tables, change, message):
    server = live_server(data_roots=[tables])
    with server.client() as c:
        r = c.post("/plans", json=absolute(tables, **change(tables)))
        assert r.status_code == 422 and message in r.json()["detail"], r.text
        assert c.get("/plans").json()["plans"] == []


def test_a_scene_that_fails_while_planning_says_why(live_server, tables):
    server = live_server(data_roots=[tables])
    with server.client() as c:
        r = c.post("/plans", json=absolute(tables, ladder=["ggx", str(tables / "not-a-bundle")]))
        plan = wait_plan(c, r.json()["id"])
    assert plan["status"] == "FAILED" and "not-a-bundle" in plan["error"] and "\n" not in plan["error"]
