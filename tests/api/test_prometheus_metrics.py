"""``/metrics`` in Prometheus' text format, parsed by prometheus-client's own parser; its counters
move as a job runs and survive a restart of the service (they come from the store)."""

from __future__ import annotations

from prometheus_client.parser import text_string_to_metric_families

from jobspecs import tiny_spec
from live_api import running_server, wait_for


def scrape(server) -> dict[tuple[str, tuple], float]:
    import httpx

    r = httpx.get(server.url + "/metrics", timeout=30)
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/plain")
    return {(s.name, tuple(sorted(s.labels.items()))): s.value
            for family in text_string_to_metric_families(r.text) for s in family.samples}


def test_metrics_move_as_a_job_runs_and_survive_a_restart(tmp_path):
    with running_server(tmp_path) as server:
        before = scrape(server)
        assert before[("neuenh_candidates_total", (("result", "ok"),))] == 0
        assert before[("neuenh_jobs", (("status", "QUEUED"),))] == 0
        with server.client() as c:
            job = c.post("/jobs", json=tiny_spec(max_rounds=2).model_dump(mode="json")).json()
            done = wait_for(c, job["id"])
        after = scrape(server)
    rounds = done["last_round"] + 1
    assert after[("neuenh_jobs", (("status", done["status"]),))] == 1
    assert after[("neuenh_candidates_total", (("result", "ok"),))] == 12 * rounds  # 12 candidates per round
    assert after[("neuenh_round_seconds_count", ())] == rounds
    assert after[("neuenh_candidate_seconds_count", ())] == 12 * rounds
    assert after[("neuenh_candidate_seconds_bucket", (("le", "+Inf"),))] == 12 * rounds
    assert after[("neuenh_queue_length", ())] == 0 and after[("neuenh_cluster_cpus", (("state", "total"),))] > 0
    with running_server(tmp_path) as again:  # a restart: the store keeps the counts
        assert scrape(again)[("neuenh_candidates_total", (("result", "ok"),))] == 12 * rounds


def test_metrics_need_the_token_when_the_service_has_one(tmp_path):
    import httpx

    with running_server(tmp_path, api_token="s3cret") as server:
        assert httpx.get(server.url + "/metrics").status_code == 401
        r = httpx.get(server.url + "/metrics", headers={"Authorization": "Bearer s3cret"})
        assert r.status_code == 200 and "neuenh_jobs" in r.text
