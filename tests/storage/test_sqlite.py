"""What only the SQLite backend has: its file settings, migrations, and a second process."""

from __future__ import annotations

import hashlib
import sqlite3
import subprocess
import os
import sys
import textwrap
import time
from pathlib import Path

import pytest
from storage_kit import N_POSITIONS, running_job

from neuenh_service.storage import JobStatus, SchemaVersionError, SQLiteJobStore, StorageError
from neuenh_service.storage.jobs import HalvingRecord, RoundKind, WarmupRecord, trained_epochs
from neuenh_service.storage.migrations import MIGRATIONS, SCHEMA_VERSION, Migration, migrate, schema_version

REPO = Path(__file__).resolve().parents[2]

# Released migrations must never change (databases in the field were built with them). When you
# add migration n, add its digest here; a changed digest means: write a new migration instead.
RELEASED = {
    1: "a9210cb3",
    2: "32a8955a",
    3: "5afb9317",
    4: "d6810963",
    5: "8f1afec2",
    6: "04e0a1fe",
    7: "07880a86",
    8: "14b1d2e0",
    9: "bfff151f",
    10: "6bcd51b8",
    11: "3f1bf306",
}


def digest(migration) -> str:
    return hashlib.sha256("\n;\n".join(migration.statements).encode()).hexdigest()[:8]


def raw(path: Path) -> sqlite3.Connection:
    return sqlite3.connect(path, isolation_level=None)


def at_version(path: Path, version: int) -> sqlite3.Connection:
    """A raw connection to a database as neuenh with schema ``version`` left it."""
    conn = raw(path)
    conn.execute("CREATE TABLE schema_version (version INTEGER NOT NULL)")
    conn.execute("INSERT INTO schema_version VALUES (?)", (version,))
    for m in MIGRATIONS[:version]:
        for statement in m.statements:
            conn.execute(statement)
    return conn


def test_released_migrations_are_frozen():
    assert [m.version for m in MIGRATIONS] == list(range(1, SCHEMA_VERSION + 1))
    assert {m.version: digest(m) for m in MIGRATIONS} == RELEASED


def test_file_settings(tmp_path):
    path = tmp_path / "sub" / "jobs.db"
    with SQLiteJobStore(path) as store:
        store.create_job({"model": "ggx"})
        conn = store._conn()  # the store's own connection: per-connection pragmas
        assert conn.execute("PRAGMA foreign_keys").fetchone()[0] == 1
        assert conn.execute("PRAGMA busy_timeout").fetchone()[0] == 10_000
        assert conn.execute("PRAGMA synchronous").fetchone()[0] == 2  # FULL
    with raw(path) as conn:
        assert conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"  # persistent in the file
        assert schema_version(conn) == SCHEMA_VERSION


@pytest.mark.parametrize("path", [":memory:", "file::memory:?cache=shared"])
def test_needs_a_file(path):
    with pytest.raises(ValueError, match="file path"):
        SQLiteJobStore(path)


def test_opens_an_empty_file(tmp_path):
    path = tmp_path / "empty.db"
    path.touch()
    with SQLiteJobStore(path) as store:
        assert store.list_jobs().jobs == ()
    with raw(path) as conn:
        assert schema_version(conn) == SCHEMA_VERSION


def test_upgrades_a_version_1_database(tmp_path):
    path = tmp_path / "v1.db"
    with at_version(path, 1) as conn:
        conn.execute("INSERT INTO jobs (id, spec, status, created_at, updated_at, idempotency_key) "
                     "VALUES ('old', '{\"model\":\"ggx\"}', 'RUNNING', 1.0, 2.0, 'k1')")
        conn.execute("INSERT INTO events (job_id, seq, time, kind, payload) "
                     "VALUES ('old', 1, 1.0, 'status', '{}')")
    with SQLiteJobStore(path) as store:
        job = store.get_job("old")
        assert (job.status, job.spec, job.created_at) == (JobStatus.RUNNING, {"model": "ggx"}, 1.0)
        assert store.create_job({"model": "ggx"}, idempotency_key="k1") == (job, False)
        assert store.append_event("old", "log").seq == 2
        assert [j.id for j in store.list_jobs(status=JobStatus.RUNNING).jobs] == ["old"]
    with raw(path) as conn:
        assert schema_version(conn) == SCHEMA_VERSION
        assert conn.execute("SELECT name FROM sqlite_master WHERE name = 'jobs_by_status'").fetchone()


def test_upgrades_a_version_2_database_moving_round_kinds_out_of_extra(tmp_path):
    """Before version 3 a polish round, a warm-up, successive halving and pruned candidates were
    keys of the rounds' ``extra`` JSON; a store written then reads as typed fields, extra cleared."""
    path = tmp_path / "v2.db"
    with at_version(path, 2) as conn:
        conn.execute("INSERT INTO jobs (id, spec, status, created_at, updated_at, last_round, current_state) "
                     "VALUES ('old', '{}', 'CONVERGED', 1.0, 2.0, 1, '01')")
        warmup = '{"epochs":4,"train_loss":0.5,"val_loss":0.6,"wall_s":3.5,"node":"n1"}'
        conn.execute("INSERT INTO rounds VALUES ('old', 0, '00', '01', 0.2, 1.0, 2.0, 'k0', ?)",
                     ('{"first_epochs":1,"prune":"halving","pruned":["10"],"radius":1,'
                      '"early_val_loss":{"00":0.4,"01":0.3,"10":0.9},"warmup":' + warmup + '}',))
        conn.execute("INSERT INTO rounds VALUES ('old', 1, '01', '01', 0.1, 3.0, 4.0, 'k1', ?)",
                     ('{"polish":"CONVERGED"}',))
        for position, (state, error) in enumerate([("00", None), ("01", None), ("10", "pruned")]):
            conn.execute("INSERT INTO candidates VALUES ('old', 0, ?, ?, 0.5, 0.2, 3, 1.0, NULL, ?, 7, '{}')",
                         (position, state, error))
        conn.execute("INSERT INTO candidates VALUES ('old', 1, 0, '01', 0.5, 0.1, 2, 1.0, NULL, NULL, 8, '{}')")
    with SQLiteJobStore(path) as store:
        first, polish = store.rounds("old")
    assert (first.kind, first.outcome, first.extra) == (RoundKind.SEARCH, None, {"radius": 1})
    assert first.warmup == WarmupRecord(epochs=4, train_loss=0.5, val_loss=0.6, wall_s=3.5, node="n1")
    assert first.halving == HalvingRecord(first_epochs=1, early_val_loss={"00": 0.4, "01": 0.3, "10": 0.9})
    assert [c.pruned for c in first.candidates] == [False, False, True]
    assert (polish.kind, polish.outcome, polish.extra, polish.warmup) == \
        (RoundKind.POLISH, JobStatus.CONVERGED, {}, None)
    assert not polish.converged  # its winner is its parent, yet the search did not converge there
    assert trained_epochs([first, polish]) == 4 + 3 + 2


def test_upgrades_a_version_8_database_moving_the_stop_reason_out_of_extra(tmp_path):
    """Before version 9 why search.stop_when ended a search was the key stop_when of its last search
    round's extra; a store written then reads it as the round's stop_reason, the other keys kept."""
    path = tmp_path / "v8.db"
    with at_version(path, 8) as conn:
        conn.execute("INSERT INTO jobs (id, spec, status, created_at, updated_at, last_round, current_state, reason) "
                     "VALUES ('old', '{}', 'STOPPED', 1.0, 2.0, 1, '11', 'stop_when')")
        for i, (parent, winner, extra) in enumerate([("00", "01", '{"radius":1}'),
                                                     ("01", "11", '{"radius":1,"stop_when":"gain 0.5 %"}')]):
            conn.execute("INSERT INTO rounds (job_id, round_index, parent_state, winner_state, winner_val_loss, "
                         "started_at, finished_at, extra) VALUES ('old', ?, ?, ?, 0.2, 1.0, 2.0, ?)",
                         (i, parent, winner, extra))
            conn.execute("INSERT INTO candidates (job_id, round_index, position, state, val_loss, epochs, wall_s) "
                         "VALUES ('old', ?, 0, ?, 0.2, 3, 1.0)", (i, winner))
    with SQLiteJobStore(path) as store:
        first, last = store.rounds("old")
    assert (first.stop_reason, first.extra) == (None, {"radius": 1})
    assert (last.stop_reason, last.extra) == ("gain 0.5 %", {"radius": 1})


def test_upgrades_a_version_9_database_counting_unfinished_preparations_from_its_events(tmp_path):
    path = tmp_path / "v9.db"
    with at_version(path, 9) as conn:
        logs = {"died_twice": ["preparing", "dataset", "preparing", "status", "preparing"],
                "interrupted": ["preparing", "preparing", "preparation_interrupted"], "prepared": ["dataset"],
                "new": []}
        for job_id, kinds in logs.items():
            conn.execute("INSERT INTO jobs (id, spec, status, created_at, updated_at) "
                         "VALUES (?, '{}', 'PREPARING', 1.0, 2.0)", (job_id,))
            for seq, kind in enumerate(kinds, 1):
                conn.execute("INSERT INTO events (job_id, seq, time, kind) VALUES (?, ?, 1.0, ?)", (job_id, seq, kind))
    with SQLiteJobStore(path) as store:
        assert {j: store.get_job(j).unfinished_preparations for j in logs} == \
            {"died_twice": 2, "interrupted": 0, "prepared": 0, "new": 0}


def test_upgrades_a_version_10_database_keeping_each_states_first_cost_from_its_events(tmp_path):
    path = tmp_path / "v10.db"
    with at_version(path, 10) as conn:
        conn.execute("INSERT INTO jobs (id, spec, status, created_at, updated_at) VALUES ('old', '{}', 'RUNNING', 1, 2)")
        payloads = ['{"state":"001","ns":350.5}', '{"state":"000","ns":120}', '{"state":"001","ns":999.0}',
                    '{"state":"010"}', '{"state":"011","ns":-1}', '{}']
        for seq, payload in enumerate(payloads, 1):
            conn.execute("INSERT INTO events (job_id, seq, time, kind, payload) VALUES ('old', ?, 1.0, 'cost', ?)",
                         (seq, payload))
        conn.execute("INSERT INTO events (job_id, seq, time, kind, payload) VALUES ('old', 7, 1.0, 'note', "
                     "'{\"state\":\"100\",\"ns\":5}')")
    with SQLiteJobStore(path) as store:
        assert store.state_costs("old") == {"001": 350.5, "000": 120.0}


def test_a_failed_migration_changes_nothing(tmp_path):
    path = tmp_path / "v1.db"
    with at_version(path, 1) as conn:
        conn.execute("CREATE TABLE jobs_by_status (x)")  # makes migration 2 fail
    with pytest.raises(StorageError, match="migration 2 .* already a table named jobs_by_status.* "
                                           "unchanged at version 1"):
        SQLiteJobStore(path)
    with raw(path) as conn:
        assert schema_version(conn) == 1


def test_pending_migrations_apply_in_one_transaction(tmp_path):
    steps = MIGRATIONS[:1] + (
        Migration(2, "add a table", ("CREATE TABLE extra (x)",)),
        Migration(3, "add a column, then fail",
                  ("ALTER TABLE jobs ADD COLUMN owner TEXT", "SELECT * FROM nope")),
    )
    with raw(tmp_path / "m.db") as conn:
        with pytest.raises(StorageError, match="migration 3 .*no such table: nope.*unchanged at version 0"):
            migrate(conn, steps)
        assert schema_version(conn) == 0
        assert conn.execute("SELECT name FROM sqlite_master").fetchall() == []
        assert migrate(conn, steps[:2]) == 2 and migrate(conn, steps[:2]) == 2
        with pytest.raises(StorageError, match="migration 3"):
            migrate(conn, steps)
        assert schema_version(conn) == 2
        assert "owner" not in [r[1] for r in conn.execute("PRAGMA table_info(jobs)")]
        with pytest.raises(ValueError, match="versions must be 1, 2, 3"):
            migrate(conn, steps[1:])


def test_refuses_a_database_from_a_newer_version(tmp_path):
    path = tmp_path / "future.db"
    SQLiteJobStore(path).close()
    with raw(path) as conn:
        conn.execute("UPDATE schema_version SET version = ?", (SCHEMA_VERSION + 1,))
    with pytest.raises(SchemaVersionError, match=f"schema version {SCHEMA_VERSION + 1}.*newer neuenh"):
        SQLiteJobStore(path)
    with raw(path) as conn:
        assert schema_version(conn) == SCHEMA_VERSION + 1


WRITER = textwrap.dedent("""
    import sys, time
    from neuenh_service.storage import SQLiteJobStore
    from storage_kit import INITIAL, N_POSITIONS, hamming_round
    store = SQLiteJobStore(sys.argv[1])
    job_id, n = sys.argv[2], int(sys.argv[3])
    print("ready", flush=True)
    sys.stdin.readline()
    state = INITIAL
    for i in range(n):
        record = hamming_round(i, state, i % N_POSITIONS)
        store.commit_round(job_id, record)
        store.append_event(job_id, "log", {"i": i})
        state = record.winner_state
        time.sleep(0.002)
    store.close()
""")


def test_another_process_reads_while_one_writes(tmp_path):
    """WAL: a reader process-side never sees half a round and is never refused by the writer."""
    path, n = tmp_path / "jobs.db", 40
    store = SQLiteJobStore(path)
    job_id = running_job(store)
    writer = subprocess.Popen(
        [sys.executable, "-c", WRITER, str(path), job_id, str(n)], cwd=REPO, stdin=subprocess.PIPE,
        stdout=subprocess.PIPE, text=True,
        env={**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), str(Path(__file__).parent)])})
    try:
        assert writer.stdout.readline().strip() == "ready"
        seen = [len(store.rounds(job_id))]
        writer.stdin.write("go\n")
        writer.stdin.flush()
        deadline = time.monotonic() + 20
        while seen[-1] < n and time.monotonic() < deadline:
            rounds = store.rounds(job_id)
            job = store.get_job(job_id)
            assert all(len(r.candidates) == N_POSITIONS + 1 for r in rounds)
            assert [r.index for r in rounds] == list(range(len(rounds)))
            assert all(a.winner_state == b.parent_state for a, b in zip(rounds, rounds[1:]))
            assert job.next_round >= len(rounds)
            seen.append(len(rounds))
        assert writer.wait(timeout=20) == 0
    finally:
        if writer.poll() is None:
            writer.kill()
            writer.wait()
        writer.stdin.close()
        writer.stdout.close()
    assert seen[0] == 0 and seen[-1] == n and seen == sorted(seen)
    assert len(set(seen)) > 2, "the reader should have observed rounds arriving"
    assert len(store.events(job_id)) == 3 + 2 * n
    store.close()
