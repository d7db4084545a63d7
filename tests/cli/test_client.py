"""``neuenh-client`` as a user runs it, in-process and as a subprocess, against a real server (uvicorn, SQLite, the
in-process executor), checked on its exit codes (ARCHITECTURE §4), its one-line errors and what it
prints against what the service holds."""

from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
import yaml

from cli_runs import run_here, run_probing_torch
from jobspecs import fit_scored_spec, tiny_spec

from live_api import live_server, running_server, wait_for  # noqa: F401  (live_server: fixture)
from neuenh.checkpoint import Bundle
from neuenh.data.directions import sample_directions
from neuenh.data.table import write_table
from neuenh.models import get_model
from neuenh_service.cli.client import main as client_main

TOKEN = "s3cret"


def environ(url, token) -> dict:
    """This environment with ``NEUENH_URL``/``NEUENH_API_TOKEN`` set as given (None: unset)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("NEUENH_")}
    env.update({k: v for k, v in (("NEUENH_URL", url), ("NEUENH_API_TOKEN", token)) if v is not None})
    return env


def client(*args, url=None, token=TOKEN, cwd=None):
    """Run ``neuenh-client ARGS`` to the end: in this process (``tests/cli_runs.py``: the command's
    exit code and output, without an interpreter's start), or with ``cwd`` in a fresh one (a working
    directory is the whole process's). ``popen`` and the torch probes run it as a process."""
    if cwd is None:
        return run_here(client_main, "neuenh-client", args, env=environ(url, token))
    return subprocess.run([sys.executable, "-m", "neuenh_service.cli.client", *map(str, args)], capture_output=True,
                          text=True, env=environ(url, token), cwd=cwd, timeout=120)


def popen(*args, url, token=TOKEN):
    """Start ``neuenh-client ARGS`` (stdout and stderr piped) with Ctrl-C's default disposition, as
    on a terminal: a suite started in the background (``cmd &``) inherits SIGINT ignored, and Python
    then never raises KeyboardInterrupt."""
    return subprocess.Popen([sys.executable, "-m", "neuenh_service.cli.client", *map(str, args)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=environ(url, token),
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def one_line_error(out, *fragments):
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in out.stderr, out.stderr
    assert lines[0].startswith("neuenh-client "), lines[0]
    for fragment in fragments:
        assert fragment in lines[0], lines[0]
    return lines[0]


def write_spec(path, **search):
    path.write_text(yaml.safe_dump(tiny_spec(**search).model_dump(mode="json")))
    return path


def long_job() -> dict:
    """A job whose round 0 alone takes seconds (cancel and shutdown act between candidates)."""
    return tiny_spec(epochs_per_round=300, max_rounds=20).model_dump(mode="json")


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    """One service with a token, shared by the module."""
    with running_server(tmp_path_factory.mktemp("client") / "data", api_token=TOKEN) as s:
        yield s


@pytest.fixture()
def api(server):
    with server.client(headers={"Authorization": f"Bearer {TOKEN}"}) as c:
        yield c


@pytest.fixture(scope="module")
def closed_url():
    """A port nothing listens on."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"http://127.0.0.1:{s.getsockname()[1]}"


@pytest.fixture(scope="module")
def submitted(server, tmp_path_factory):
    """``submit SPEC --wait`` of a two-round job, run once: (the process, the job as served)."""
    spec = write_spec(tmp_path_factory.mktemp("spec") / "tiny.yaml", max_rounds=2)
    out = client("submit", spec, "--wait", "--name", "tiny", "--interval", "0.1", url=server.url)
    assert out.returncode in (0, 1), out.stderr
    with server.client(headers={"Authorization": f"Bearer {TOKEN}"}) as c:
        return out, c.get(f"/jobs/{out.stdout.strip()}").json()


# -- submit -----------------------------------------------------------------------------------
def test_submit_wait_follows_the_rounds_and_exits_0(submitted):
    out, job = submitted
    assert out.returncode == 0, out.stderr
    assert re.fullmatch(r"[0-9a-f]{32}\n", out.stdout)  # just the id: JOB=$(neuenh-client submit ...)
    assert job["status"] in ("CONVERGED", "STOPPED") and job["name"] == "tiny"
    rounds = re.findall(r"^round (\d+): (committed|converged), winner (\d{11}) val ", out.stderr, re.M)
    assert [int(r[0]) for r in rounds] == list(range(job["last_round"] + 1))
    assert rounds[-1][2] == job["current_state"]
    assert f"job {job['id']}: {job['status']} after {job['last_round'] + 1} round(s)" in out.stderr


def test_submit_from_flags_only_and_again_with_the_same_key(live_server):
    s = live_server(max_epochs=1)
    args = ("submit", "--name", "from-flags", "--epochs", "1", "--max-rounds", "4", "--radius", "0",
            "--idempotency-key", "k-1", "--json")
    first, imported_torch = run_probing_torch("neuenh_service.cli.client", *args, env=environ(s.url, None))
    again = client(*args, url=s.url, token=None)
    assert first.returncode == again.returncode == 0, first.stderr + again.stderr
    assert not imported_torch, "checking a job spec and sending it needs no torch"
    job = json.loads(first.stdout)
    assert job["name"] == "from-flags" and job["model"] == "ggx"
    assert job["spec"]["search"] == {**job["spec"]["search"], "epochs_per_round": 1, "max_rounds": 4, "radius": 0}
    assert job["spec"]["data"][0]["source"] == "synthetic_zoo"
    assert json.loads(again.stdout)["id"] == job["id"] and "already submitted with this key" in again.stderr


def test_a_budget_stops_the_job_and_every_view_says_so(server, tmp_path):
    spec = tmp_path / "long.yaml"
    spec.write_text(yaml.safe_dump(long_job()))
    out = client("submit", spec, "--budget", "wall=1.5s,cpu=1h", "--priority", "3", "--wait", "--interval", "0.1",
                 url=server.url)
    assert out.returncode == 0, out.stderr  # STOPPED is a success: the model so far is usable
    job_id = out.stdout.strip()
    assert re.search(rf"job {job_id}: STOPPED \(budget\) after \d+ round\(s\)", out.stderr), out.stderr
    shown = json.loads(client("status", job_id, "--json", url=server.url).stdout)
    assert shown["spec"]["budget"] == {"wall_s": 1.5, "cpu_s": 3600.0} and shown["priority"] == 3
    assert shown["reason"] == "budget" and shown["used_wall_s"] >= 1.5
    text = client("status", job_id, url=server.url).stdout
    assert "status     STOPPED (budget)" in text and re.search(r"used wall  [\d.]+ s of a 1.5 s budget", text), text
    listed = client("status", url=server.url).stdout
    assert re.search(rf"^{job_id}\s+STOPPED \(budget\)\s", listed, re.M), listed


def test_submit_over_a_service_limit_exits_2_naming_it(live_server, tmp_path):
    s = live_server(max_epochs=1)
    out = client("submit", write_spec(tmp_path / "spec.yaml", epochs_per_round=2), url=s.url, token=None)
    assert out.returncode == 2
    one_line_error(out, "neuenh-client submit: error:", "search.epochs_per_round: 2", "NEUENH_MAX_EPOCHS")
    assert out.stdout == ""


@pytest.mark.parametrize("args,message", [
    (["submit", "BAD_SPEC"], "search.radius"),
    (["submit", "--model", "phong"], "unknown model 'phong'"),
    (["fit", "JOB", "BAD_TABLE"], "f_r has negative values"),
    (["download", "JOB", "-o", "FULL_DIR"], "is not empty; use --force"),
], ids=["invalid-spec", "unknown-model", "bad-table", "download-over-a-directory"])
def test_usage_errors_exit_2_before_contacting_the_service(tmp_path, closed_url, args, message):
    bad_spec = tmp_path / "bad.yaml"
    bad_spec.write_text(yaml.safe_dump({**tiny_spec().model_dump(mode="json"), "search": {"radius": 9}}))
    np.savez(tmp_path / "bad.npz", wi=[[0, 0, 1.0]], wo=[[0, 0, 1.0]], f_r=[[-1.0, 0, 0]])
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "keep.txt").write_text("mine")
    paths = {"BAD_SPEC": bad_spec, "BAD_TABLE": tmp_path / "bad.npz", "FULL_DIR": tmp_path / "full"}
    out, imported_torch = run_probing_torch("neuenh_service.cli.client", *[paths.get(a, a) for a in args],
                                            env=environ(closed_url, TOKEN), cwd=tmp_path)
    assert out.returncode == 2  # 3 would mean it tried the (closed) service
    assert not imported_torch  # a job spec is checked against its model's graph, which needs no torch
    one_line_error(out, message)
    assert (tmp_path / "full" / "keep.txt").read_text() == "mine"


@pytest.mark.parametrize("budget,message", [
    ("cpu=-1h", "'-1h': a budget must be a positive duration"),
    ("memory=1h", "unknown budget 'memory'; use wall=DURATION and/or cpu=DURATION"),
    ("wall=soon", "'soon' is not a duration (e.g. 90, 90s, 15m, 2h, 1d)"),
])
def test_a_bad_budget_is_a_usage_error(closed_url, budget, message):
    out = client("submit", "--budget", budget, url=closed_url)
    assert out.returncode == 2 and "Traceback" not in out.stderr  # argparse: the usage, then the error
    assert out.stderr.strip().splitlines()[-1] == f"neuenh-client submit: error: argument --budget: {message}"


# -- reaching the service -----------------------------------------------------------------------
@pytest.mark.parametrize("args", [["status"], ["jobs"], ["watch", "0" * 32]], ids=["status", "jobs", "watch"])
def test_an_unreachable_service_exits_3_in_one_line(closed_url, args):
    out = client(*args, url=closed_url)
    assert out.returncode == 3
    one_line_error(out, f"cannot reach {closed_url} (connection refused)", "NEUENH_URL")


@pytest.mark.parametrize("flag,env,code,message", [
    (None, None, 3, "requires a token (missing bearer token"),
    ("wrong", None, 3, "refused the token (invalid bearer token)"),
    (None, "wrong", 3, "refused the token (invalid bearer token)"),
    (TOKEN, None, 0, None),
    (None, TOKEN, 0, None),
    (TOKEN, "wrong", 0, None),  # the flag wins over the environment
], ids=["none", "wrong-flag", "wrong-env", "right-flag", "right-env", "flag-over-env"])
def test_auth_matrix(server, flag, env, code, message):
    out = client("jobs", "--json", *(["--token", flag] if flag else []), url=server.url, token=env)
    assert out.returncode == code, out.stderr
    if code:
        one_line_error(out, message, "NEUENH_API_TOKEN")
    else:
        assert isinstance(json.loads(out.stdout), list)
    assert TOKEN not in out.stdout + out.stderr and "wrong" not in out.stderr


# -- following and reading jobs ----------------------------------------------------------------
def test_status_of_a_job_and_of_the_service(server, submitted):
    job = submitted[1]
    out = client("status", job["id"], url=server.url)
    assert out.returncode == 0, out.stderr
    assert f"status     {job['status']}" in out.stdout and f"state {job['current_state']}" in out.stdout
    out = client("status", "--json", url=server.url)
    assert out.returncode == 0, out.stderr
    overview = json.loads(out.stdout)
    assert overview["health"]["auth"] is True and job["id"] in [j["id"] for j in overview["jobs"]]
    out = client("status", url=server.url)
    assert out.returncode == 0 and out.stdout.startswith(f"service {server.url}: ok")
    assert re.search(rf"^{job['id']}\s+{job['status']}\s+{job['last_round'] + 1}\s+{job['current_state']}\s",
                     out.stdout, re.M), out.stdout


def test_history_table_and_json_agree_with_the_service(server, api, submitted):
    job = submitted[1]
    served = api.get(f"/jobs/{job['id']}/history").json()
    out = client("history", job["id"], "--json", url=server.url)
    assert out.returncode == 0 and json.loads(out.stdout) == served

    out = client("history", job["id"], url=server.url)
    assert out.returncode == 0, out.stderr
    header, *rows = out.stdout.splitlines()
    assert header.split()[:2] == ["round", "parent"] and len(rows) == len(served["rounds"])
    positions = get_model("ggx").positions
    for row, r in zip(rows, served["rounds"]):
        changed = [("+" if b == "1" else "-") + positions[i]
                   for i, (a, b) in enumerate(zip(r["parent_state"], r["winner_state"])) if a != b]
        ok = sum(c["ok"] for c in r["candidates"])
        start = served["start_val_loss"]
        assert r["change"] == (" ".join(changed) or "stay")  # the served change, derived independently
        expected = [str(r["round"]), r["parent_state"], "->", r["winner_state"], *(changed or ["stay"]),
                    *(["converged"] if r["converged"] else []), f"{r['winner_val_loss']:.5f}",
                    f"{100 * (r['winner_val_loss'] / start - 1):+.1f}%",
                    f"{ok}/{len(r['candidates'])}", f"{r['wall_s']:.1f}s"]
        assert row.split() == expected


def test_history_of_a_search_scored_by_fit_shows_the_fit_score(server, api):
    r = api.post("/jobs", json=fit_scored_spec(max_rounds=1).model_dump(mode="json"))
    assert r.status_code == 202, r.text
    job = wait_for(api, r.json()["id"])
    served = api.get(f"/jobs/{job['id']}/history").json()
    out = client("history", job["id"], url=server.url)
    assert out.returncode == 0, out.stderr
    header, row = out.stdout.splitlines()
    assert "val loss  fit score" in header
    r0 = served["rounds"][0]
    assert f"{r0['winner_val_loss']:.5f} {r0['winner_fit_score']:.5f}" in " ".join(row.split())
    watched = client("watch", job["id"], url=server.url)  # its committed rounds say which loss selected
    assert watched.returncode == 0, watched.stderr
    assert re.search(rf"^round 0: (committed|converged), winner \d{{11}} fit score {r0['winner_fit_score']:.5f} ",
                     watched.stderr, re.M), watched.stderr


def test_history_into_a_closed_pipe_ends_quietly(server, submitted):
    job_id = submitted[1]["id"]
    piped = subprocess.run(f"{sys.executable} -m neuenh_service.cli.client history {job_id} | head -1", shell=True,
                           capture_output=True, text=True, env=environ(server.url, TOKEN))
    assert piped.stdout.startswith("round") and piped.stdout.count("\n") == 1 and piped.stderr == ""
    p = popen("history", job_id, "--json", url=server.url)
    p.stdout.close()  # the reader is gone before the client writes a byte
    assert p.wait(60) == 141 and p.stderr.read() == ""


@pytest.mark.parametrize("command", ["status", "history", "watch"])
def test_what_only_reads_the_service_answers_without_importing_torch(server, submitted, command):
    """torch is ~1.5 s of a client's start: only what validates or loads a model locally imports it."""
    job_id = submitted[1]["id"]
    out, imported_torch = run_probing_torch("neuenh_service.cli.client", command, job_id, env=environ(server.url, TOKEN))
    assert out.returncode == 0 and not imported_torch, out.stderr
    assert job_id in out.stdout + out.stderr or command == "history" and out.stdout.startswith("round")


def test_watch_a_live_job_ctrl_c_then_cancel(server, api, submitted):
    job_id = api.post("/jobs", json=long_job()).json()["id"]
    watcher = popen("watch", job_id, "--interval", "0.1", url=server.url)
    assert watcher.stderr.readline().startswith(f"job {job_id}: ")  # a status line: it is following
    watcher.send_signal(signal.SIGINT)
    assert watcher.wait(30) == 130
    assert "keeps running" in watcher.stderr.read()
    assert not api.get(f"/jobs/{job_id}").json()["terminal"]  # watching stopped, not the job

    watcher = popen("watch", job_id, "--interval", "0.1", "--json", url=server.url)
    assert watcher.stderr.readline().startswith(f"job {job_id}: ")
    out = client("cancel", job_id, url=server.url)
    assert out.returncode == 0 and f"job {job_id}: CANCELLED" in out.stdout
    assert watcher.wait(30) == 1  # the job did not succeed
    assert f"job {job_id}: CANCELLED" in watcher.stderr.read()
    assert json.loads(watcher.stdout.read())["status"] == "CANCELLED"
    wait_for(api, job_id)


def test_watch_waits_out_a_lost_service_then_exits_3(live_server):
    s = live_server()
    with s.client() as c:
        job_id = c.post("/jobs", json=long_job()).json()["id"]
    watcher = popen("watch", job_id, "--interval", "0.1", "--reconnect", "1", url=s.url)
    first = watcher.stderr.readline()
    assert first.startswith(f"job {job_id}: "), first + watcher.stderr.read()
    s.stop()  # the running job stops at a safe point, to resume on the next start
    assert watcher.wait(30) == 3
    *_, lost, error = watcher.stderr.read().strip().splitlines()  # after any status lines
    assert lost == f"lost {s.url}; trying again for 1 s"
    assert error.startswith(f"neuenh-client watch: error: cannot reach {s.url} (connection refused)")


@pytest.mark.parametrize("which,code,message", [
    ("cancelled", 2, "is already CANCELLED; only unfinished jobs can be cancelled"),
    ("finished", 2, "only unfinished jobs can be cancelled"),
    ("missing", 2, "no job 'nosuchjob'"),
])
def test_cancel_what_cannot_be_cancelled(server, api, submitted, which, code, message):
    if which == "cancelled":
        job_id = api.post("/jobs", json=tiny_spec(max_rounds=20).model_dump(mode="json")).json()["id"]
        api.post(f"/jobs/{job_id}/cancel")
    else:
        job_id = submitted[1]["id"] if which == "finished" else "nosuchjob"
    out = client("cancel", job_id, url=server.url)
    assert out.returncode == code
    one_line_error(out, "neuenh-client cancel: error:", message)


# -- models and fits ---------------------------------------------------------------------------
def test_download_extracts_a_bundle_and_refuses_to_overwrite(server, submitted, tmp_path):
    job = submitted[1]
    out = client("download", job["id"], url=server.url, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    target = tmp_path / f"neuenh-{job['id']}"
    assert out.stdout.strip() == target.name
    bundle = Bundle.load(target)
    assert bundle.model.state == job["current_state"] and bundle.provenance["job"] == job["id"]
    assert sorted(p.name for p in tmp_path.iterdir()) == [target.name]  # no staging left behind

    again = client("download", job["id"], url=server.url, cwd=tmp_path)
    assert again.returncode == 2
    one_line_error(again, "is not empty; use --force")
    forced = client("download", job["id"], "--force", "--json", url=server.url, cwd=tmp_path)
    assert forced.returncode == 0, forced.stderr
    assert json.loads(forced.stdout)["state"] == job["current_state"]
    assert Bundle.load(target).model.state == job["current_state"]


def test_export_writes_a_jobs_materials_as_glsl(server, submitted, tmp_path):
    job = submitted[1]
    assert client("download", job["id"], "-o", tmp_path / "m.zip", url=server.url).returncode == 0
    with zipfile.ZipFile(tmp_path / "m.zip") as z:
        first = json.loads(z.read("model.json"))["materials"][0]
    out = client("export", job["id"], "--format", "glsl", "--material", first, url=server.url, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    material, generic = sorted(out.stdout.split(), key=lambda p: p.endswith("-generic.glsl"))
    assert Path(material).name.endswith(".glsl") and Path(generic).name == "ggx-generic.glsl"
    assert "vec3 neuenh_brdf(vec3 wi, vec3 wo)" in (tmp_path / material).read_text()
    assert "float p[" in (tmp_path / generic).read_text()
    one_line_error(client("export", job["id"], "--format", "glsl", url=server.url, cwd=tmp_path),
                   "exists and is not empty")
    one_line_error(client("export", job["id"], "--format", "glsl", "--material", "nope", "-o", tmp_path / "n",
                          url=server.url), "holds no material 'nope'")


def test_download_keeps_a_zip(server, submitted, tmp_path):
    out = client("download", submitted[1]["id"], "-o", tmp_path / "m.zip", url=server.url)
    assert out.returncode == 0, out.stderr
    with zipfile.ZipFile(tmp_path / "m.zip") as z:
        assert sorted(z.namelist()) == ["materials.safetensors", "model.json", "weights.safetensors"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.zip"]


@pytest.fixture(scope="module")
def ggx_table(tmp_path_factory):
    """A plain GGX material at 1500 sampled direction pairs."""
    wi, wo = (d.float() for d in sample_directions(1500, seed=3))
    params = {"normal": np.zeros(2), "t_theta": np.zeros(1), "rho_d": np.full(3, 0.2), "rho_s": np.ones(3),
              "alpha_x": [0.15], "alpha_y": [0.3], "f0": [0.04]}
    import torch

    f = get_model("ggx").evaluate(wi, wo, {k: torch.tensor(v, dtype=torch.float32) for k, v in params.items()})
    return write_table(tmp_path_factory.mktemp("tables") / "steel.npz", wi, wo, f.detach())


@pytest.mark.parametrize("as_json", [True, False], ids=["json", "table"])
def test_fit_measurements_with_a_jobs_model(server, submitted, ggx_table, as_json):
    """The table is checked here and fitted on the service: the client itself never imports torch."""
    job = submitted[1]
    out, imported_torch = run_probing_torch("neuenh_service.cli.client", "fit", job["id"], ggx_table, "--epochs", "40",
                                            *(["--json"] if as_json else []), env=environ(server.url, TOKEN))
    assert out.returncode == 0 and not imported_torch, out.stderr
    if as_json:
        report = json.loads(out.stdout)
        (m,) = report["materials"]
        assert report["state"] == job["current_state"] and report["round"] == job["last_round"]
        assert m["name"] == "steel" and m["samples"] == 1500 and np.isfinite(m["loss"])
        assert {"rho_d", "alpha_x", "f0"} <= set(m["params"])
        assert all(np.isfinite(v).all() for v in m["params"].values())
    else:
        first, material = out.stdout.splitlines()[:2]
        assert first.startswith(f"job {job['id']} round {job['last_round']}: ggx (state {job['current_state']})")
        assert re.match(r"\s+steel: log-L1 \d+\.\d{5}\s", material)


def _neuenh_fit_default() -> str:
    from neuenh_service.cli.main import build_parser

    return build_parser(["fit"]).parse_args(["fit", "m.npz"]).capacity


def _client_fit_default() -> str:
    from neuenh_service.cli.client import build_parser

    return build_parser().parse_args(["fit", "JOB", "m.npz"]).capacity


def _service_fit_default() -> str:
    from neuenh_service.api.app import create_app
    from neuenh_service.api.settings import Settings

    schemas = create_app(Settings()).openapi()["components"]["schemas"]
    (form,) = [schema for name, schema in schemas.items() if name.startswith("Body_fit_job")]
    return form["properties"]["capacity"]["default"]


@pytest.mark.parametrize("default_of", [_neuenh_fit_default, _client_fit_default, _service_fit_default],
                         ids=["neuenh fit", "neuenh-client fit", "POST /v1/jobs/{id}/fit"])
def test_a_users_fit_chooses_the_capacity_per_material_unless_told(default_of):
    """The three ways a user fits a material fit it the same way when not told: ``auto``
    (``neuenh.capacities.USER_CAPACITY``), each material's capacity validated on its own samples."""
    from neuenh.capacities import USER_CAPACITY

    assert default_of() == USER_CAPACITY == "auto"


def test_fit_a_measured_file_drawn_here_as_neuenh_fit_draws_it(server, submitted, tmp_path):
    """A MERL file is drawn by the client (``cli.draws``: ``--samples`` pairs, half near the mirror) and
    fitted on the service as the table of those pairs, under the file's name."""
    from neuenh.data.merl import write_merl
    from neuenh.data.synthetic import synthetic_ggx

    (material,) = synthetic_ggx(1, seed=8, noise_sigma=0.0)
    merl = write_merl(tmp_path / "gold.binary", lambda wi, wo: material.evaluate(wi, wo).numpy())
    job = submitted[1]
    out = client("fit", job["id"], merl, "--samples", "800", "--epochs", "20", "--json", url=server.url)
    assert out.returncode == 0, out.stderr
    (m,) = json.loads(out.stdout)["materials"]
    assert m["name"] == "gold" and m["samples"] == 800 and np.isfinite(m["loss"])


def test_plan_a_scene_on_the_service_wait_and_save_its_files(live_server, tmp_path):
    from scene_files import scene, write_module_bundle, write_tables

    (tmp_path / "roots").mkdir()
    tables = write_tables(tmp_path / "roots")
    server = live_server(data_roots=[tables], api_token=TOKEN)
    write_module_bundle(tables / "searched")
    # paths relative to the scene file (a bundle folder's too): the client sends them as the service must read them
    data = scene(tables, ladder=["ggx", {"model": "searched", "capacity": "last-layer"}, "nbrdf"])
    (tables / "scene.yaml").write_text(yaml.safe_dump(data))
    out = client("plan", tables / "scene.yaml", "--wait", "-o", tmp_path / "files", url=server.url)
    assert out.returncode == 0, out.stderr
    assert re.search(r"gloss +ggx +[0-9.]+", out.stdout) and re.search(r"retro +NBRDF", out.stdout)
    assert "frame: plan" in out.stdout and "materials" in out.stderr
    assert sorted(p.name for p in (tmp_path / "files").iterdir()) == ["cost_vs_error.png", "plan.json", "plan.md"]
    ladder = json.loads((tmp_path / "files" / "plan.json").read_text())["ladder"]
    assert [r["key"] for r in ladder] == ["ggx", f"{tables.resolve() / 'searched'}:last-layer", "nbrdf"]
    bad = dict(data, ladder=[])
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump(bad))
    one_line_error(client("plan", tmp_path / "bad.yaml", url=server.url), "ladder: List should have at least 1 item")
    # where the files go is refused before anything is submitted
    plans_before = len(server.app.state.plans.list_plans())
    one_line_error(client("plan", tables / "scene.yaml", "-o", tmp_path / "files", url=server.url), "needs --wait")
    one_line_error(client("plan", tables / "scene.yaml", "--wait", "-o", tables / "scene.yaml", url=server.url),
                   "exists and is not a folder")
    assert len(server.app.state.plans.list_plans()) == plans_before


def test_plan_uploads_the_scenes_files_to_a_service_that_cannot_read_them(live_server, tmp_path):
    from scene_files import scene, write_tables

    (tmp_path / "mine").mkdir()
    tables = write_tables(tmp_path / "mine")
    server = live_server(data_roots=[tmp_path / "elsewhere"], api_token=TOKEN)  # the files are not under its roots
    (tables / "scene.yaml").write_text(yaml.safe_dump(scene(tables)))
    refused = client("plan", tables / "scene.yaml", url=server.url)
    one_line_error(refused, "materials.0:", "is outside the data roots")
    out, imported_torch = run_probing_torch("neuenh_service.cli.client", "plan", tables / "scene.yaml", "--upload",
                                            "--wait", "--json", env=environ(server.url, TOKEN))
    assert out.returncode == 0, out.stderr
    assert not imported_torch, "checking a scene file and sending it needs no torch (neuenh.scene.spec)"
    plan = json.loads(out.stdout)
    assert {m["name"]: m["chosen"] for m in plan["plan"]["materials"]} == {"gloss": "ggx", "retro": "nbrdf"}
    twice = dict(scene(tables), materials=[{"path": "gloss.npz"}, {"path": str(tmp_path / "other" / "gloss.npz")}])
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "gloss.npz").write_bytes((tables / "retro.npz").read_bytes())
    (tables / "twice.yaml").write_text(yaml.safe_dump(twice))
    one_line_error(client("plan", tables / "twice.yaml", "--upload", url=server.url), "share the file name 'gloss.npz'")


def test_a_plan_cancelled_a_busy_service_and_a_damaged_file_each_explained(live_server, tmp_path):
    """Issue 26: plans can be cancelled from the client (cases 2); a busy fit slot (429, case 3) and
    a damaged stored file (507, case 10) are each one line saying what to do, not "the service failed"."""
    from scene_files import runaway, write_tables

    tables = write_tables(tmp_path)
    server = live_server(data_roots=[tmp_path], api_token=TOKEN)
    with server.client(headers={"Authorization": f"Bearer {TOKEN}"}) as c:
        job = wait_for(c, c.post("/jobs", json=tiny_spec(max_rounds=1).model_dump(mode="json")).json()["id"])
        plan = c.post("/plans", json=runaway(tables)).json()
    cancelled = client("cancel", "--plan", plan["id"], url=server.url)
    assert cancelled.returncode == 0, cancelled.stderr
    assert cancelled.stdout.startswith(f"plan {plan['id']}: CANCELLED (it keeps its 0 planned material(s)")
    one_line_error(client("cancel", "--plan", plan["id"], url=server.url), "is already CANCELLED")

    lock = server.app.state.fit_lock
    assert lock.acquire(timeout=30)  # a fit holds the slot
    try:
        busy = client("fit", job["id"], tables / "gloss.npz", url=server.url)
    finally:
        lock.release()
    assert busy.returncode == 3
    one_line_error(busy, f"{server.url} is busy (another fit or measurement upload is running", "retry in 10 s")

    for path in (server.settings.data_dir / "artifacts" / "sha256").rglob("*"):
        if path.is_file():  # every checkpoint of the job
            data = bytearray(path.read_bytes())
            data[len(data) // 2] ^= 0x01
            path.write_bytes(bytes(data))
    damaged = client("download", job["id"], "-o", tmp_path / "m.zip", url=server.url)
    assert damaged.returncode == 1 and not (tmp_path / "m.zip").exists()
    one_line_error(damaged, "a file the service stored is damaged and was not used", "is corrupt",
                   "restore it from a backup, resubmitting will not help")
