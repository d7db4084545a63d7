"""The dashboard at ``/`` in a real headless Chromium (Debian's package, driven by Playwright)
against a live server: the jobs table, the running jobs side by side, a job's trail through the
hypercube, the loss chart, the model download, live polling of a running job, a job stopped by its
budget, the token form, and a screenshot that is not blank
(``NEUENH_UPDATE_SCREENSHOT=1`` also saves it to ``docs/img/dashboard.png`` for the README; tests
never write into the repository otherwise).

Every request the page makes to anything but the loopback server is blocked and recorded, and
each test asserts there was none: the page works offline."""

from __future__ import annotations

import os
import re
import shutil
import threading
import time
import zipfile
from pathlib import Path
from urllib.parse import urlparse

import numpy as np
import pytest
from PIL import Image

from jobspecs import tiny_spec
from live_api import running_server, wait_for
from neuenh_service.orchestrator.spec import parse_spec

CHROMIUM = Path("/usr/bin/chromium")
if not CHROMIUM.exists():
    pytest.skip("Debian's chromium is not installed (/usr/bin/chromium); apt-get install chromium",
                allow_module_level=True)
sync_api = pytest.importorskip("playwright.sync_api", reason="the playwright package is not installed")

SCREENSHOT = Path(__file__).resolve().parents[2] / "docs" / "img" / "dashboard.png"
LOOPBACK = {"127.0.0.1", "localhost", "::1"}
TIMEOUT_MS = 30_000


def body(name: str | None = None, **search) -> dict:
    spec = tiny_spec(**search).model_dump(mode="json")
    spec["name"] = name
    return spec


def demo_body() -> dict:
    """A job with a few rounds to show."""
    return parse_spec({
        "name": "zoo-ggx-demo",
        "search": {"epochs_per_round": 6, "max_rounds": 4},
        "train": {"batch_size": 1000, "lr": 5e-3},
        "data": [{"source": "synthetic_zoo", "materials": 2, "samples": 1000, "seed": 1}],
    }).model_dump(mode="json")


def diff(a: str, b: str) -> list[int]:
    return [i for i, (x, y) in enumerate(zip(a, b)) if x != y]


# -- fixtures ---------------------------------------------------------------------------------
@pytest.fixture(scope="module", autouse=True)
def _one_torch_thread():
    """Jobs train in this process (in-process executor) next to Chromium and the server: on a
    small machine one torch thread is several times faster than two fighting for the cores."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def browser():
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=str(CHROMIUM), args=[
            "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
            "--disable-background-networking", "--disable-component-update", "--disable-sync"])
        yield b
        b.close()


@pytest.fixture()
def page(browser):
    """A fresh page (own storage) whose non-loopback requests are blocked; at the end, no such
    request may have been attempted and no script error may have been thrown."""
    context = browser.new_context(viewport={"width": 1280, "height": 900}, accept_downloads=True)
    outside: list[str] = []
    errors: list[str] = []

    def guard(route):
        url = route.request.url
        if urlparse(url).hostname in LOOPBACK:
            route.continue_()
        else:
            outside.append(url)
            route.abort()

    context.route("**/*", guard)
    pg = context.new_page()
    pg.set_default_timeout(TIMEOUT_MS)
    pg.on("pageerror", lambda e: errors.append(str(e)))
    yield pg
    context.close()
    assert outside == [], f"the page tried to reach beyond the service: {outside}"
    assert errors == [], f"script errors: {errors}"


MAX_RUNNING = 3  # jobs the module's server runs at once, whatever the machine's CPUs


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    with running_server(tmp_path_factory.mktemp("dashboard") / "data", max_running_jobs=MAX_RUNNING) as s:
        yield s


@pytest.fixture(scope="module")
def finished(server):
    """A tiny job run to the end: 2 rounds of 12 candidates, plus its history."""
    with server.client() as c:
        r = c.post("/jobs", json=body("tiny", max_rounds=2))
        assert r.status_code == 202, r.text
        job = wait_for(c, r.json()["id"])
        assert job["status"] in ("STOPPED", "CONVERGED"), job["error"]
        return job, c.get(f"/jobs/{job['id']}/history").json()


class Gate:
    """Paces the in-process executor so a test sees a job mid-round whatever the machine's speed:
    open, candidates train freely; held, each waits for a permit (``release(n)``)."""

    def __init__(self):
        self._cond = threading.Condition()
        self._permits: int | None = None  # None: open

    def hold(self) -> None:
        with self._cond:
            self._permits = 0

    def release(self, n: int) -> None:
        with self._cond:
            self._permits = (self._permits or 0) + n
            self._cond.notify_all()

    def open(self) -> None:
        with self._cond:
            self._permits = None
            self._cond.notify_all()

    def wait(self) -> None:
        with self._cond:
            self._cond.wait_for(lambda: self._permits is None or self._permits > 0, timeout=120)
            if self._permits:
                self._permits -= 1


@pytest.fixture(scope="module")
def gate():
    from neuenh_service.workers import inline

    g, train = Gate(), inline.run_candidate

    def paced(*args, **kwargs):
        g.wait()
        return train(*args, **kwargs)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(inline, "run_candidate", paced)
        yield g
        g.open()


@pytest.fixture(scope="module")
def demo_job(server, gate):
    """A job with a few rounds, submitted with the gate held: no candidate trains until a test
    releases some (the polling test watches it run; the screenshot test opens the gate)."""
    gate.hold()
    with server.client() as c:
        r = c.post("/jobs", json=demo_body())
        assert r.status_code == 202, r.text
        return r.json()


def submit(client, spec: dict) -> str:
    r = client.post("/jobs", json=spec)
    assert r.status_code == 202, r.text
    return r.json()["id"]


def training(job: dict) -> bool:
    """Whether the job's round has started (its progress counts candidates)."""
    return bool((job["progress"] or {}).get("total"))


def open_job(page, server, job_id: str, rounds: int) -> None:
    page.goto(f"{server.url}/#job={job_id}")
    page.wait_for_function("n => document.querySelectorAll('#trail tbody tr').length === n", arg=rounds)


# -- tests ------------------------------------------------------------------------------------
def test_job_carries_its_position_names(finished):
    from neuenh.models import get_model

    assert finished[0]["positions"] == list(get_model("ggx").positions)


def test_api_docs_render_with_the_network_cut(page, server):
    """Swagger UI at /docs from the package's assets: every /v1 operation listed, nothing fetched
    from outside (the page fixture blocks and reports any such request)."""
    page.goto(f"{server.url}/docs")
    page.wait_for_selector(".opblock-summary-path")
    paths = set(page.eval_on_selector_all(".opblock-summary-path", "els => els.map(e => e.dataset.path)"))
    assert {"/v1/jobs", "/v1/jobs/{job_id}/history", "/v1/health"} <= paths
    assert page.title() == "neuenh API"


def test_jobs_table_lists_the_job_and_links_to_it(page, server, finished):
    job, _ = finished
    page.goto(server.url + "/")
    row = page.locator(f"#jobs tbody tr[data-job='{job['id']}']")
    row.wait_for()
    assert "tiny" in row.inner_text() and job["status"] in row.inner_text()
    assert job["current_state"] in row.inner_text()
    assert page.locator("#job").is_hidden()  # nothing selected yet
    row.locator("td").nth(2).click()  # a click anywhere on the row selects the job
    page.wait_for_url(f"**/#job={job['id']}")
    page.locator("#trail tbody tr").first.wait_for()
    assert "selected" in (row.get_attribute("class") or "")


def test_trail_has_one_row_per_round_and_the_positions_as_headers(page, server, finished):
    job, history = finished
    rounds = history["rounds"]
    open_job(page, server, job["id"], len(rounds))
    headers = page.eval_on_selector_all("#trail thead th.pos", "ths => ths.map(th => th.textContent)")
    assert headers == job["positions"]
    rows = page.locator("#trail tbody tr")
    for i, r in enumerate(rounds):
        row = rows.nth(i)
        assert row.get_attribute("data-round") == str(r["round"])
        digits = row.locator("td.digit")
        assert "".join(digits.all_text_contents()) == r["winner_state"]
        flipped = digits.evaluate_all("tds => tds.flatMap((td, i) => td.classList.contains('flipped') ? [i] : [])")
        assert flipped == diff(r["parent_state"], r["winner_state"])
        change = row.locator("td.change").inner_text()
        assert change == r["change"] if flipped else change.startswith("stay")  # as the API describes it
        assert f"{r['winner_val_loss']:.4g}"[:5] in row.inner_text()
    # The winner's state, digit by digit with the position names, as the final model.
    final = page.locator("#final-state")
    assert job["current_state"] in final.inner_text()
    assert page.locator("#final-state .chip").count() == len(job["positions"])
    assert page.locator("#final-heading").text_content() == "Final model"
    assert page.locator("#progress").is_hidden()
    assert page.locator("#card-rounds").inner_text() == str(len(rounds))
    gain = 100 * (1 - rounds[-1]["winner_val_loss"] / history["start_val_loss"])
    assert page.locator("#card-gain").inner_text() == f"{'−' if gain >= 0 else '+'}{abs(gain):.1f}% loss"


def test_chart_has_a_point_per_candidate_and_marks_the_winners(page, server, finished):
    job, history = finished
    rounds = history["rounds"]
    open_job(page, server, job["id"], len(rounds))
    points = page.locator("#chart svg .pt")
    assert points.count() == sum(len(r["candidates"]) for r in rounds) == 12 * len(rounds)
    winners = page.eval_on_selector_all("#chart svg .pt.winner",
                                        "cs => cs.map(c => [c.dataset.round, c.dataset.state])")
    assert sorted(winners) == sorted([str(r["round"]), r["winner_state"]] for r in rounds)
    # Each point sits at its candidate's loss: a lower loss is drawn lower down (larger SVG y).
    first = rounds[0]["candidates"]
    ok = sorted((c for c in first if c["ok"]), key=lambda c: c["val_loss"])
    y = {c.get_attribute("data-state"): float(c.get_attribute("cy"))
         for c in page.locator("#chart svg .pt[data-round='0']").all()}
    assert y[ok[0]["state"]] > y[ok[-1]["state"]]
    assert page.locator("#chart svg .pt.failed").count() == sum(not c["ok"] for r in rounds for c in r["candidates"])


def fake_job(positions: list[str], rounds: int, per_round: int = 12) -> tuple[dict, dict]:
    """A job and history as the API would serve them: many rounds, losses over two decades, a
    failed candidate every fifth, and m-ary digits."""
    n, state, history = len(positions), "0" * len(positions), []
    for k in range(rounds):
        candidates = []
        for i in range(per_round):
            s = list(state)
            s[i % n] = "0" if state[i % n] != "0" else str(1 + i % 3)
            ok = (k * per_round + i) % 5 != 3
            candidates.append({"state": "".join(s) if i else state, "ok": ok, "winner": False,
                               "train_loss": None, "val_loss": (2.0 * 0.7 ** k * (1 + 0.1 * i)) if ok else None,
                               "epochs": 30, "wall_s": 1.0, "node": "n1",
                               "error": None if ok else "RuntimeError: loss is NaN", "seed": i})
        winner = min((c for c in candidates if c["ok"]), key=lambda c: c["val_loss"])
        winner["winner"] = True
        for c in candidates:
            c["change"] = " ".join(f"{positions[i]}[{state[i]}->{c['state'][i]}]" for i in diff(state, c["state"])) or "stay"
        history.append({"round": k, "kind": "search", "parent_state": state, "winner_state": winner["state"],
                        "change": winner["change"], "gain_over_start": None,
                        "winner_val_loss": winner["val_loss"], "converged": winner["state"] == state,
                        "started_at": "2026-01-01T00:00:00Z", "finished_at": "2026-01-01T00:01:00Z",
                        "recovered": 5 if k == 1 else 0, "wall_s": 60.0, "candidates": candidates, "extra": {}})
        state = winner["state"]
    url = "/v1/jobs/fake"
    job = {"id": "fake", "name": "synthetic <history>", "model": "ggx", "status": "STOPPED", "terminal": True,
           "error": None, "reason": None, "priority": 0, "used_wall_s": 1800.0, "used_cpu_s": 1800.0,
           "created_at": "2026-01-01T00:00:00Z", "updated_at": "2026-01-01T00:30:00Z",
           "last_round": rounds - 1, "current_state": state, "spec": {}, "progress": None, "positions": positions,
           "links": {"self": url, "history": url + "/history", "model": url + "/model", "cancel": url + "/cancel"}}
    return job, {"job_id": "fake", "status": "STOPPED", "terminal": True, "reason": None, "current_state": state,
                 "start_val_loss": None, "gain_over_start": None,
                 "rounds": history, "next_since_round": rounds}


def test_many_rounds_failed_candidates_and_other_digits_are_drawn(page, server, finished):
    """A history the tiny jobs do not produce (served by the test in place of the API)."""
    job, history = fake_job(finished[0]["positions"], rounds=14)
    page.route("**/v1/jobs/fake", lambda route: route.fulfill(json=job))
    page.route("**/v1/jobs/fake/history?*", lambda route: route.fulfill(json=history))
    open_job(page, server, "fake", 14)
    candidates = [c for r in history["rounds"] for c in r["candidates"]]
    assert page.locator("#chart svg .pt").count() == len(candidates)
    failed = page.locator("#chart svg .pt.failed")
    assert failed.count() == sum(not c["ok"] for c in candidates) > 0
    assert "RuntimeError: loss is NaN" in failed.first.locator("title").text_content()
    assert "(log)" in page.locator("#chart svg .y-label").text_content()  # two decades: log scale
    assert page.locator("#job-title").inner_text() == "synthetic <history>"
    digits = page.locator("#trail tbody tr").last.locator("td.digit").all_text_contents()
    assert "".join(digits) == job["current_state"]
    assert page.locator("#trail tbody td.digit.d2").count() > 0  # another module choice, its own colour
    # Round 1 read 5 finished candidates back after a restart; the others read none.
    recovered = page.locator("#trail tbody tr .recovered")
    assert recovered.all_text_contents() == ["5 recovered"]
    assert page.locator("#trail tbody tr[data-round='1'] .recovered").count() == 1


def test_a_search_scored_by_fit_shows_each_winners_fit_score_beside_its_val_loss(page, server, finished):
    """search.score: fit (served as the history's rounds' winner_fit_score): the trail gains a fit score
    column, marked as the one that selects, and each candidate's point tells both losses."""
    job, history = fake_job(finished[0]["positions"], rounds=3)
    job["spec"] = {"search": {"score": "fit"}}
    for r in history["rounds"]:
        for i, c in enumerate(r["candidates"]):
            c["fit_score"] = 0.03 + 0.001 * i if c["ok"] else None
        r["winner_fit_score"] = next(c["fit_score"] for c in r["candidates"] if c["winner"])
    history["score"] = "fit"
    page.route("**/v1/jobs/fake", lambda route: route.fulfill(json=job))
    page.route("**/v1/jobs/fake/history?*", lambda route: route.fulfill(json=history))
    open_job(page, server, "fake", 3)
    headers = page.eval_on_selector_all("#trail thead th", "ths => ths.map(th => th.textContent)")
    assert "Winner fit score (selects)" in headers and "Winner val loss" in headers
    shown = page.locator("#trail tbody td.fit-score").all_text_contents()
    assert [float(x) for x in shown] == pytest.approx([r["winner_fit_score"] for r in history["rounds"]], rel=1e-3)
    title = page.locator("#chart svg .pt.winner").first.locator("title").text_content()
    assert "val loss" in title and "fit score" in title


def test_download_button_yields_the_model_zip(page, server, finished, tmp_path):
    job, history = finished
    open_job(page, server, job["id"], len(history["rounds"]))
    with page.expect_download() as info:
        page.click("#download")
    download = info.value
    assert download.suggested_filename == f"neuenh-{job['id']}-round{job['last_round']:04d}.zip"
    path = tmp_path / download.suggested_filename
    download.save_as(path)
    with zipfile.ZipFile(path) as archive:
        assert {"model.json", "weights.safetensors"} <= set(archive.namelist())
    page.wait_for_function("document.getElementById('download-note').textContent.startsWith('Downloaded')")


def test_unknown_job_says_so(page, server, finished):
    page.goto(f"{server.url}/#job=nope")
    page.locator("#job-error").wait_for()
    assert "No such job" in page.locator("#job-error").inner_text()
    page.locator("#jobs tbody tr").first.wait_for()  # the list still works (it loads on its own)


def test_running_job_shows_progress_and_new_rounds_without_reload(page, server, demo_job, gate, client):
    job_id = demo_job["id"]
    page.goto(f"{server.url}/#job={job_id}")
    page.evaluate("window.__samePage = true")
    page.wait_for_function("document.getElementById('job-status').textContent === 'RUNNING'")
    try:
        gate.release(12 + 4)  # round 0, then 4 candidates of round 1
        # Round 0 shows up in the trail and round 1's live progress below the cards.
        page.wait_for_function("document.querySelectorAll('#trail tbody tr').length === 1")
        page.wait_for_function(
            "document.getElementById('progress-label').textContent === 'Round 1: 4 of 12 candidates trained'")
        assert page.locator("#progress").is_visible()
        assert page.locator("#progress-fill").evaluate("e => e.style.width") == f"{100 * 4 / 12:.1f}%"
        assert "training… 4/12" in page.locator("#trail tfoot").inner_text()
        assert page.locator("#final-heading").text_content().startswith("Current model")
        page.wait_for_function(  # the jobs table shows it too
            f"(document.querySelector(\"#jobs tr[data-job='{job_id}']\") || {{}}).textContent?.includes('round 1 · 4/12')")
        job = client.get(f"/jobs/{job_id}").json()
        assert job["status"] == "RUNNING" and job["last_round"] == 0
    finally:
        gate.open()
    # The next rounds appear by polling alone, until the job ends.
    page.wait_for_function("document.querySelectorAll('#trail tbody tr').length >= 2")
    job = wait_for(client, job_id)
    page.wait_for_function("s => document.getElementById('job-status').textContent === s", arg=job["status"])
    assert page.locator("#progress").is_hidden()
    page.wait_for_function("n => document.querySelectorAll('#trail tbody tr').length === n", arg=job["last_round"] + 1)
    assert page.evaluate("window.__samePage") is True


def test_screenshot_of_a_finished_job_is_not_blank(page, server, demo_job, gate, client, tmp_path):
    gate.open()
    job = wait_for(client, demo_job["id"])
    open_job(page, server, job["id"], job["last_round"] + 1)
    page.wait_for_function("document.getElementById('conn').textContent === 'live'")
    shot = tmp_path / "dashboard.png"
    page.screenshot(path=str(shot), full_page=True)
    image = np.asarray(Image.open(shot).convert("RGB"))
    assert image.shape[1] == 1280 and image.shape[0] >= 900
    colours = np.unique(image.astype(np.int32) @ np.array([1 << 16, 1 << 8, 1]))
    assert len(colours) > 200, f"only {len(colours)} distinct colours"
    assert image.std() > 20
    # Not one flat block either: every horizontal third of the page has content.
    for part in np.array_split(image, 3, axis=0):
        assert part.std() > 10
    if os.environ.get("NEUENH_UPDATE_SCREENSHOT"):
        shutil.copyfile(shot, SCREENSHOT)


def test_cancel_button_cancels_a_running_job(page, server, gate, client):
    gate.hold()  # the job stays in round 0 until the gate opens
    try:
        r = client.post("/jobs", json=body("to cancel", max_rounds=3))
        assert r.status_code == 202, r.text
        job_id = r.json()["id"]
        page.goto(f"{server.url}/#job={job_id}")
        page.wait_for_function("document.getElementById('job-status').textContent === 'RUNNING'")
        page.click("#cancel")
        assert page.locator("#cancel").inner_text() == "Really cancel?"  # a second click confirms
        page.click("#cancel")
        page.wait_for_function("document.getElementById('job-status').textContent === 'CANCELLED'")
        assert client.get(f"/jobs/{job_id}").json()["status"] == "CANCELLED"
        assert page.locator("#cancel").is_hidden()
    finally:
        gate.open()
    wait_for(client, job_id)


def test_running_jobs_are_shown_side_by_side_with_their_live_progress(page, server, gate, client):
    """Two jobs at once: a card each in "Running now", side by side, with its round's progress and
    what its candidate in flight holds; updated by polling, gone when the jobs end."""
    gate.hold()  # each job's candidates wait for permits
    try:
        first = submit(client, body("first", max_rounds=1))
        wait_for(client, first, until=training)
        gate.release(2)  # before the second job starts: 2 of the first's candidates, none of its
        wait_for(client, first, until=lambda j: j["progress"]["done"] == 2)
        second = submit(client, body("second", max_rounds=1))
        wait_for(client, second, until=training)
        page.goto(server.url + "/")
        page.evaluate("window.__samePage = true")
        page.wait_for_function("document.querySelectorAll('#running .run-card').length === 2")
        assert page.locator("#running-count").inner_text() == f"2 of at most {MAX_RUNNING} running"
        cards = page.locator("#running .run-card")
        assert [cards.nth(i).get_attribute("data-job") for i in (0, 1)] == [first, second]  # oldest first
        a, b = (cards.nth(i).bounding_box() for i in (0, 1))
        assert a["y"] == b["y"] and a["x"] + a["width"] <= b["x"]  # side by side
        progress = client.get(f"/jobs/{first}").json()["progress"]
        card = cards.nth(0)
        assert card.locator(".run-name").inner_text() == "first"
        assert card.locator(".run-progress").inner_text() == "round 0 · 2/12 candidates"
        assert card.locator(".mini-fill").evaluate("e => e.style.width") == f"{100 * 2 / 12:.1f}%"
        assert f"{progress['best_val_loss']:.4g}"[:5] in card.locator(".run-best").inner_text()
        assert card.locator(".run-slots").inner_text() == "1 candidate · 1 CPU"  # the inline executor trains one
        assert cards.nth(1).locator(".run-progress").inner_text() == "round 0 · 0/12 candidates"
        assert cards.nth(1).locator(".run-best").inner_text() == "best –"

        gate.release(1)  # to either job: the cards follow the API by polling
        def done() -> list[int]:
            return [client.get(f"/jobs/{j}").json()["progress"]["done"] for j in (first, second)]

        wait_for(client, first, until=lambda _: sum(done()) == 3)
        expected = [f"round 0 · {n}/12 candidates" for n in done()]
        page.wait_for_function("want => [...document.querySelectorAll('#running .run-progress')]"
                               ".map(e => e.textContent).join() === want.join()", arg=expected)

        cards.nth(1).locator(".run-progress").click()  # a click on a card opens its job
        page.wait_for_url(f"**/#job={second}")
        page.wait_for_function("document.getElementById('job-title').textContent === 'second'")
        assert "selected" in (cards.nth(1).get_attribute("class") or "")
    finally:
        gate.open()
    for job_id in (first, second):
        assert wait_for(client, job_id)["status"] in ("STOPPED", "CONVERGED")
    page.locator("#running-panel").wait_for(state="hidden")
    assert page.locator("#running .run-card").count() == 0
    assert page.evaluate("window.__samePage") is True


def test_a_job_stopped_by_its_budget_says_so(page, server, client):
    """STOPPED with reason "budget": the badge, the jobs table and the model text say so, and the
    job's facts show what it spent of its budget."""
    spec = body("budgeted", max_rounds=20)
    spec["budget"] = {"wall_s": 0.2}
    job = wait_for(client, submit(client, spec))
    assert (job["status"], job["reason"]) == ("STOPPED", "budget")
    assert job["used_wall_s"] >= 0.2
    page.goto(f"{server.url}/#job={job['id']}")
    page.wait_for_function("document.getElementById('job-status').textContent === 'STOPPED (budget)'")
    assert re.search(r"(^| · )wall [0-9.]+ s of 0\.2 s( · |$)", page.locator("#job-meta").inner_text())
    assert "its budget ran out" in page.locator("#final-text").inner_text()
    row = page.locator(f"#jobs tbody tr[data-job='{job['id']}']")
    row.wait_for()
    assert row.locator(".badge").inner_text() == "STOPPED (budget)"
    assert "budget spent" in row.inner_text()


def test_token_protected_server_asks_for_the_token_then_works(page, live_server):
    server = live_server(api_token="s3cret-token")
    name = '<img src=x onerror="window.__pwned=1">tiny'
    with server.client(headers={"Authorization": "Bearer s3cret-token"}) as c:
        r = c.post("/jobs", json=body(name, max_rounds=1))
        assert r.status_code == 202, r.text
        job = wait_for(c, r.json()["id"])
    page.goto(server.url + "/")
    page.locator("#auth").wait_for()
    assert page.locator("#jobs-panel").is_hidden()
    page.fill("#token", "wrong")
    page.click("#token-submit")
    page.locator("#auth-error").wait_for()
    assert "refused" in page.locator("#auth-error").inner_text()
    page.fill("#token", "s3cret-token")
    page.click("#token-submit")
    row = page.locator(f"#jobs tbody tr[data-job='{job['id']}']")
    row.wait_for()
    # The job's name is shown as text, never parsed as HTML.
    assert row.locator("a").inner_text() == name
    assert page.locator("#jobs img").count() == 0 and page.evaluate("window.__pwned") is None
    assert page.evaluate("localStorage.getItem('neuenh.token')") == "s3cret-token"
    row.locator("a").click()
    page.wait_for_function("n => document.querySelectorAll('#trail tbody tr').length === n", arg=job["last_round"] + 1)
    with page.expect_download() as info:  # fetch with the bearer header, then a blob URL
        page.click("#download")
    assert zipfile.is_zipfile(info.value.path())
    # A reload keeps the token.
    page.reload()
    page.locator(f"#jobs tbody tr[data-job='{job['id']}']").wait_for()
    assert page.locator("#auth").is_hidden()


def test_a_plan_shows_its_materials_totals_and_plot(page, tmp_path):
    """A scene planned on the service: the plans table lists it, and its view shows each material's
    chosen rung, the frame totals and the cost-against-error plot (fetched with the token)."""
    from scene_files import scene, write_tables

    (tmp_path / "roots").mkdir()
    tables = write_tables(tmp_path / "roots")
    data = scene(tables)
    data["materials"] = [{**m, "path": str(tables / m["path"])} for m in data["materials"]]
    with running_server(tmp_path / "data", data_roots=[tables], api_token="t0k") as server:
        with server.client(headers={"Authorization": "Bearer t0k"}) as c:
            plan_id = c.post("/plans", json=data).json()["id"]
            deadline = time.monotonic() + 120
            while not c.get(f"/plans/{plan_id}").json()["terminal"]:
                assert time.monotonic() < deadline
                time.sleep(0.2)
        page.goto(f"{server.url}/#plan={plan_id}")
        page.fill("#token", "t0k")
        page.click("#token-submit")
        page.wait_for_selector(f"#plans tr[data-plan='{plan_id}']")
        page.wait_for_function("document.querySelectorAll('#plan-table tbody tr').length === 2")
        rows = page.eval_on_selector_all("#plan-table tbody tr", "rs => rs.map(r => r.cells[2].textContent)")
        assert rows == ["ggx", "NBRDF (per material)"]
        assert "frame cost" in page.text_content("#plan-totals")
        page.wait_for_function("document.querySelector('#plan-plot').naturalWidth > 100")


def test_cancel_button_cancels_a_running_plan(page, tmp_path):
    """Issue 26, case 2: a runaway plan (NBRDF for the most epochs allowed) is cancelled from its
    view with two clicks; the plan is CANCELLED on the service and the button goes."""
    from scene_files import runaway, write_tables

    data = runaway(write_tables(tmp_path))
    with running_server(tmp_path / "data", data_roots=[tmp_path], api_token="t0k") as server:
        with server.client(headers={"Authorization": "Bearer t0k"}) as c:
            plan_id = c.post("/plans", json=data).json()["id"]
            page.goto(f"{server.url}/#plan={plan_id}")
            page.fill("#token", "t0k")
            page.click("#token-submit")
            page.locator("#plan-cancel").wait_for()
            page.click("#plan-cancel")
            assert page.locator("#plan-cancel").inner_text() == "Really cancel?"  # a second click confirms
            page.click("#plan-cancel")
            try:
                page.wait_for_function("document.getElementById('plan-meta').textContent.startsWith('CANCELLED')")
            except sync_api.TimeoutError:
                pytest.fail(f"the plan's view shows {page.locator('#plan-meta').inner_text()!r} (error: "
                            f"{page.locator('#error').inner_text()!r}); the service: {c.get(f'/plans/{plan_id}').json()}")
            assert c.get(f"/plans/{plan_id}").json()["status"] == "CANCELLED"
            assert page.locator("#plan-cancel").is_hidden()


def test_a_plan_view_polls_on_after_a_failed_request(page, tmp_path):
    """A poll of the plan that fails (here one 503) shows the error and is tried again: the view
    still reaches the plan's end (cancelled from elsewhere meanwhile) instead of keeping the status
    it showed before the failure."""
    from scene_files import runaway, write_tables

    data = runaway(write_tables(tmp_path))
    with running_server(tmp_path / "data", data_roots=[tmp_path]) as server, server.client() as c:
        plan_id = c.post("/plans", json=data).json()["id"]
        page.goto(f"{server.url}/#plan={plan_id}")
        page.locator("#plan-cancel").wait_for()
        failed = threading.Event()

        def fail_once(route):
            if failed.is_set():
                route.continue_()
            else:
                failed.set()
                route.fulfill(status=503, content_type="application/json",
                              body='{"detail": "the service is busy (a test)"}')

        page.route(f"**/v1/plans/{plan_id}", fail_once)
        page.wait_for_function("document.getElementById('error').textContent.includes('busy')")
        assert c.post(f"/plans/{plan_id}/cancel").json()["status"] == "CANCELLED"
        page.wait_for_function("document.getElementById('plan-meta').textContent.startsWith('CANCELLED')")
