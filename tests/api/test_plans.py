"""``/v1/plans`` on a live server: a scene planned as a persisted job kind — queued, run, its files
served; the same plan resumed after a restart keeps the materials it had planned; scenes reading
files outside the data roots or naming nothing real are refused in one line; a scene sent with its
measured files (``/v1/plan-uploads``) is planned from them."""

from __future__ import annotations

import hashlib
import time

import pytest
import yaml

from live_api import wait_plan
from scene_files import scene, write_tables
from neuenh_service.storage import SQLitePlanStore


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
    (lambda t: {"ladder": [{"model": "/tmp", "capacity": "auto"}]}, "ladder.0: /tmp is outside the data roots"),
    (lambda t: {"ladder": []}, "ladder: List should have at least 1 item"),
    (lambda t: {"tolerance": {"metric": "ssim"}}, "exactly one of 'relative'"),
    (lambda t: {"materials": [{"path": str(t / ("x" * 300 + ".npz"))}]}, "is not a usable path (File name too long)"),
], ids=["material-outside", "bundle-outside", "model-bundle-outside", "empty-ladder", "no-tolerance",
        "material-name-too-long"])
def test_bad_scenes_are_refused_before_anything_is_stored(live_server, tables, change, message):
    server = live_server(data_roots=[tables])
    with server.client() as c:
        r = c.post("/plans", json=absolute(tables, **change(tables)))
        assert r.status_code == 422 and message in r.json()["detail"], r.text
        assert c.get("/plans").json()["plans"] == []


@pytest.mark.parametrize("entry, said", [
    (lambda t: str(t / "not-a-bundle"), "not-a-bundle"),
    (lambda t: "é" * 300, "neither an analytical model"),  # a name no file system holds: Path.exists() raises
], ids=["missing-bundle", "name-too-long"])
def test_a_scene_that_fails_while_planning_says_why(live_server, tables, entry, said):
    server = live_server(data_roots=[tables])
    with server.client() as c:
        r = c.post("/plans", json=absolute(tables, ladder=["ggx", entry(tables)]))
        assert r.status_code == 202, r.text
        plan = wait_plan(c, r.json()["id"])
    assert plan["status"] == "FAILED" and said in plan["error"] and "\n" not in plan["error"]


def upload(c, data: dict, files: dict[str, bytes], **headers):
    return c.post("/plan-uploads", data={"scene": yaml.safe_dump(data)},
                  files=[("files", (name, content)) for name, content in files.items()], headers=headers)


def test_a_scene_sent_with_its_files_is_planned_from_them(live_server, tables, tmp_path):
    """No data roots at all: the service reads only what was sent, kept by its digest until the plan
    has ended."""
    server = live_server()
    sent = {name: (tables / name).read_bytes() for name in ("gloss.npz", "retro.npz")}
    with server.client() as c:
        r = upload(c, scene(tables), sent, **{"Idempotency-Key": "k1"})
        assert r.status_code == 202, r.text
        plan = wait_plan(c, r.json()["id"])
        again = upload(c, scene(tables), sent, **{"Idempotency-Key": "k1"})
    assert plan["status"] == "DONE", plan["error"]
    assert {m["name"]: m["chosen"] for m in plan["plan"]["materials"]} == {"gloss": "ggx", "retro": "nbrdf"}
    assert again.status_code == 200 and again.json()["id"] == plan["id"]
    kept = tmp_path / "data" / "uploads"
    deadline = time.monotonic() + 10
    while any(kept.iterdir()) and time.monotonic() < deadline:  # released once the plan has ended
        time.sleep(0.05)
    assert list(kept.iterdir()) == [], f"kept after the plan ended: {sorted(p.name for p in kept.iterdir())}"


@pytest.mark.parametrize("case, message", [
    ("unnamed", "sheen.npz uploaded but named by no material's path"),
    ("not-measured", "junk.npz: unrecognised content"),
    ("too-large", "gloss.npz: 1600 measurements exceed this service's limit of 1000 per material"),
    ("missing", "materials.1: retro.npz is outside the data roots"),
    ("not-yaml", "scene: not valid YAML or JSON"),
])
def test_bad_uploads_are_refused_and_nothing_is_kept(live_server, tables, tmp_path, case, message):
    server = live_server(max_samples=1000 if case == "too-large" else 1_000_000)
    data = scene(tables)
    files = {"gloss.npz": (tables / "gloss.npz").read_bytes(), "retro.npz": (tables / "retro.npz").read_bytes()}
    if case == "unnamed":
        files["sheen.npz"] = (tables / "sheen.npz").read_bytes()
    if case == "not-measured":
        data["materials"][1]["path"] = "junk.npz"
        files = {"junk.npz": b"not a table at all", "gloss.npz": files["gloss.npz"]}
    if case == "missing":
        del files["retro.npz"]
    with server.client() as c:
        if case == "not-yaml":
            r = c.post("/plan-uploads", data={"scene": "{a: [1, 2"}, files=[("files", ("gloss.npz", b"x"))])
        else:
            r = upload(c, data, files)
        assert r.status_code == 422 and message in r.json()["detail"], r.text
        assert "/tmp" not in r.json()["detail"].replace(str(tables), "")  # names the upload, not the folder
        assert c.get("/plans").json()["plans"] == []
    kept = tmp_path / "data" / "uploads"
    assert not kept.exists() or list(kept.iterdir()) == []  # neither a partial file nor a good one it sent


def test_a_damaged_upload_fails_its_plan_instead_of_being_used(live_server, tables, tmp_path):
    kept = tmp_path / "data" / "uploads"
    kept.mkdir(parents=True)
    content = (tables / "gloss.npz").read_bytes()
    digest = hashlib.sha256(content).hexdigest()
    (kept / digest).write_bytes(content[:-16] + bytes(16))  # the disk changed it after the upload
    store = SQLitePlanStore(tmp_path / "data" / "jobs.sqlite")
    plan, _ = store.create_plan(scene(tables, materials=[{"path": str(kept / digest), "sha256": digest,
                                                          "name": "gloss"}]))  # as the upload route stores it
    store.start(plan.id, 1)
    store.close()
    server = live_server()
    with server.client() as c:
        done = wait_plan(c, plan.id)
    assert done["status"] == "FAILED" and "does not match its sha256" in done["error"], done
