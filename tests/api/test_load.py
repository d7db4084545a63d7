"""50 concurrent pollers of a job's history while it trains, beside 300 idle connections (more
than the 256 that once took the service down, issue 17): every answer is a 200 with rounds that
only ever extend (the figures of this load are in docs/BENCHMARKS.md, bench/bench_api.py)."""

from __future__ import annotations

import socket
import threading
import time

import httpx

from jobspecs import tiny_spec
from live_api import TERMINAL


def test_fifty_pollers_while_a_job_trains(live_server):
    server = live_server()
    host, port = server.url.removeprefix("http://").split(":")
    idle = [socket.create_connection((host, int(port))) for _ in range(300)]  # no token, no bytes
    with server.client() as c:
        job_id = c.post("/jobs", json=tiny_spec(max_rounds=2).model_dump(mode="json")).json()["id"]
    failures: list[str] = []
    seen: list[list[int]] = [[] for _ in range(50)]

    def poll(i: int) -> None:
        since, terminal = 0, False
        with httpx.Client(base_url=server.url + "/v1", timeout=60) as client:
            while not terminal:
                r = client.get(f"/jobs/{job_id}/history", params={"since_round": since})
                if r.status_code != 200:
                    failures.append(f"{r.status_code}: {r.text[:200]}")
                    return
                h = r.json()
                seen[i] += [rnd["round"] for rnd in h["rounds"]]
                since, terminal = h["next_since_round"], h["status"] in TERMINAL
                time.sleep(0.2)  # a busy dashboard; the GIL is shared with the job training in-process

    threads = [threading.Thread(target=poll, args=(i,)) for i in range(50)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    for sock in idle:
        sock.close()
    assert not failures, failures[:3]
    assert not any(t.is_alive() for t in threads)
    with server.client() as c:
        committed = [r["round"] for r in c.get(f"/jobs/{job_id}/history").json()["rounds"]]
    assert committed and all(rounds == committed for rounds in seen)  # each round once, in order
