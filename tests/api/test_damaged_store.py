"""A damaged job database (issue 17, case 7): found at start in one line (exit 2, what to do),
and a job the service cannot update is reported broken by /health instead of looking RUNNING."""

from __future__ import annotations

import sqlite3
import time

from neuenh_service.cli.main import main
from neuenh_service.storage import SQLiteJobStore
from jobspecs import tiny_spec

from live_api import running_server


def serve(data_dir, capsys) -> tuple[int, list[str]]:
    code = main(["serve", "--port", "0", "--data-dir", str(data_dir)])
    return code, capsys.readouterr().err.strip().splitlines()


def test_a_corrupt_database_header_is_one_line_and_exit_2(tmp_path, capsys):
    (tmp_path / "jobs.sqlite").write_bytes(b"this is not a database" * 100)
    code, err = serve(tmp_path, capsys)
    assert code == 2 and len(err) == 1 and "jobs.sqlite" in err[0], err


def test_a_damaged_page_is_found_at_start(tmp_path, capsys):
    path = tmp_path / "jobs.sqlite"
    with SQLiteJobStore(path) as store:
        job, _ = store.create_job(tiny_spec().model_dump(mode="json"))
        for i in range(300):  # several pages of events
            store.append_event(job.id, "note", {"text": "x" * 200, "i": i})
    with sqlite3.connect(path) as conn:  # fold the WAL back so the pages live in the main file
        conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    data = bytearray(path.read_bytes())
    page = 4096
    for at in range(3 * page, len(data) - page, 7 * page):  # scribble over a few b-tree pages
        data[at:at + 64] = b"\xff" * 64
    path.write_bytes(bytes(data))
    code, err = serve(tmp_path, capsys)
    assert code == 2 and len(err) == 1, err
    assert "damaged" in err[0] or "malformed" in err[0], err
    assert "restore it from a backup" in err[0] or "jobs.sqlite" in err[0]


def test_a_job_the_store_cannot_update_is_reported_by_health(tmp_path):
    with running_server(tmp_path) as server:
        queue = server.app.state.job_queue

        def damaged(job_id):  # the store fails under the job (fault injected at the runner)
            raise sqlite3.DatabaseError("database disk image is malformed")

        queue.orchestrator.run = damaged
        with server.client() as c:
            job = c.post("/jobs", json=tiny_spec().model_dump(mode="json")).json()
            for _ in range(100):
                health = c.get("/health").json()
                if health["broken_jobs"]:
                    break
                time.sleep(0.05)
        assert health["status"] == "degraded"
        assert "malformed" in health["broken_jobs"][job["id"]]
