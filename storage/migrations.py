"""Forward-only schema migrations of the SQLite job store.

``MIGRATIONS`` is an append-only list: step ``n`` upgrades a database from version ``n - 1`` to
``n``. Never edit a released step; add a new one. ``migrate`` applies every pending step, and the
version bump, in ONE transaction (SQLite DDL is transactional), so a database is always at a
released version. The version lives in the one-row table ``schema_version``; a database without
that table is version 0 (new, or empty).
"""

from __future__ import annotations

import sqlite3
from collections.abc import Sequence
from dataclasses import dataclass

from .errors import SchemaVersionError, StorageError


@dataclass(frozen=True)
class Migration:
    version: int
    description: str
    statements: tuple[str, ...]


MIGRATIONS: tuple[Migration, ...] = (
    Migration(1, "jobs, rounds, candidates, events", (
        """CREATE TABLE jobs (
            seq             INTEGER PRIMARY KEY AUTOINCREMENT,  -- creation order, for paging
            id              TEXT    NOT NULL UNIQUE,
            spec            TEXT    NOT NULL,                   -- canonical JSON
            status          TEXT    NOT NULL,                   -- checked in Python (JobStatus)
            created_at      REAL    NOT NULL,                   -- UTC epoch seconds
            updated_at      REAL    NOT NULL,
            error           TEXT,
            idempotency_key TEXT    UNIQUE,
            last_round      INTEGER,
            current_state   TEXT
        )""",
        """CREATE TABLE rounds (
            job_id          TEXT    NOT NULL REFERENCES jobs(id) ON DELETE CASCADE,
            round_index     INTEGER NOT NULL CHECK (round_index >= 0),
            parent_state    TEXT    NOT NULL,
            winner_state    TEXT    NOT NULL,
            winner_val_loss REAL    NOT NULL,
            started_at      REAL    NOT NULL,
            finished_at     REAL    NOT NULL,
            artifact_key    TEXT,
            extra           TEXT    NOT NULL DEFAULT '{}',
            PRIMARY KEY (job_id, round_index)
        )""",
        """CREATE TABLE candidates (
            job_id          TEXT    NOT NULL,
            round_index     INTEGER NOT NULL,
            position        INTEGER NOT NULL,                   -- order within the round
            state           TEXT    NOT NULL CHECK (length(state) > 0),
            train_loss      REAL,                               -- NULL: not finite
            val_loss        REAL,
            epochs          INTEGER NOT NULL CHECK (epochs >= 0),
            wall_s          REAL    NOT NULL CHECK (wall_s >= 0),
            node            TEXT,
            error           TEXT,
            seed            INTEGER,
            extra           TEXT    NOT NULL DEFAULT '{}',
            PRIMARY KEY (job_id, round_index, position),
            UNIQUE (job_id, round_index, state),
            FOREIGN KEY (job_id, round_index)
                REFERENCES rounds(job_id, round_index) ON DELETE CASCADE
        )""",
        """CREATE TABLE events (
            job_id          TEXT    NOT NULL REFERENCES jobs(id) ON DELETE CASCADE,
            seq             INTEGER NOT NULL CHECK (seq >= 1),
            time            REAL    NOT NULL,
            kind            TEXT    NOT NULL,
            payload         TEXT    NOT NULL DEFAULT '{}',
            PRIMARY KEY (job_id, seq)
        )""",
    )),
    Migration(2, "index for listing jobs by status", (
        "CREATE INDEX jobs_by_status ON jobs(status, seq)",
    )),
    Migration(3, "round kinds, warm-up, halving and pruned candidates as columns, out of extra", (
        "ALTER TABLE rounds ADD COLUMN kind TEXT NOT NULL DEFAULT 'search'",
        "ALTER TABLE rounds ADD COLUMN outcome TEXT",  # a polish round: the search's outcome
        "ALTER TABLE rounds ADD COLUMN warmup TEXT",  # JSON WarmupRecord, round 0
        "ALTER TABLE rounds ADD COLUMN halving TEXT",  # JSON HalvingRecord
        "ALTER TABLE candidates ADD COLUMN pruned INTEGER NOT NULL DEFAULT 0",
        # Stores written before this version kept these as keys of the rounds' extra JSON.
        """UPDATE rounds SET kind = 'polish', outcome = json_extract(extra, '$.polish')
           WHERE json_extract(extra, '$.polish') IS NOT NULL""",
        """UPDATE rounds SET warmup = json(json_extract(extra, '$.warmup'))
           WHERE json_type(extra, '$.warmup') = 'object'""",
        """UPDATE rounds SET halving = json_object('first_epochs', json_extract(extra, '$.first_epochs'),
                                                 'early_val_loss', json(json_extract(extra, '$.early_val_loss')))
           WHERE json_extract(extra, '$.prune') = 'halving'""",
        """UPDATE candidates SET pruned = 1 WHERE EXISTS (
               SELECT 1 FROM rounds r, json_each(r.extra, '$.pruned') p
               WHERE r.job_id = candidates.job_id AND r.round_index = candidates.round_index
                 AND p.value = candidates.state)""",
        """UPDATE rounds SET extra = json_remove(extra, '$.polish', '$.warmup', '$.prune', '$.first_epochs',
                                                 '$.pruned', '$.early_val_loss')""",
    )),
    Migration(4, "each job's owner (the name of the token that submitted it)", (
        "ALTER TABLE jobs ADD COLUMN owner TEXT",  # NULL: submitted without named tokens
        "CREATE INDEX jobs_by_owner ON jobs(owner, seq)",
    )),
    Migration(5, "finished candidates before their round commits; usage and reason of a job; recovered count", (
        """CREATE TABLE finished_candidates (
            job_id          TEXT    NOT NULL REFERENCES jobs(id) ON DELETE CASCADE,
            round_index     INTEGER NOT NULL CHECK (round_index >= 0),
            phase           TEXT    NOT NULL CHECK (length(phase) > 0),
            state           TEXT    NOT NULL CHECK (length(state) > 0),
            recorded        INTEGER NOT NULL,                   -- arrival order within the job
            record          TEXT    NOT NULL,                   -- canonical JSON CandidateRecord
            artifact_key    TEXT,                               -- its trained bundle; NULL: failed
            PRIMARY KEY (job_id, round_index, phase, state)
        )""",
        "ALTER TABLE jobs ADD COLUMN reason TEXT",  # why a job that did not fail ended, e.g. 'budget'
        "ALTER TABLE jobs ADD COLUMN used_wall_s REAL NOT NULL DEFAULT 0 CHECK (used_wall_s >= 0)",
        "ALTER TABLE jobs ADD COLUMN used_cpu_s REAL NOT NULL DEFAULT 0 CHECK (used_cpu_s >= 0)",
        "ALTER TABLE rounds ADD COLUMN recovered INTEGER NOT NULL DEFAULT 0 CHECK (recovered >= 0)",
    )),
    Migration(6, "scene plans and their planned materials", (
        """CREATE TABLE plans (
            seq             INTEGER PRIMARY KEY AUTOINCREMENT,  -- creation order
            id              TEXT    NOT NULL UNIQUE,
            scene           TEXT    NOT NULL,                   -- canonical JSON
            status          TEXT    NOT NULL,                   -- checked in Python (PlanStatus)
            created_at      REAL    NOT NULL,
            updated_at      REAL    NOT NULL,
            owner           TEXT,
            error           TEXT,
            idempotency_key TEXT    UNIQUE,
            materials_total INTEGER CHECK (materials_total >= 0),
            result          TEXT                                -- canonical JSON, when DONE
        )""",
        "CREATE INDEX plans_by_owner ON plans(owner, seq)",
        """CREATE TABLE plan_materials (
            plan_id         TEXT    NOT NULL REFERENCES plans(id) ON DELETE CASCADE,
            name            TEXT    NOT NULL,
            recorded        INTEGER NOT NULL,                   -- recording order within the plan
            result          TEXT    NOT NULL,                   -- canonical JSON MaterialPlan
            PRIMARY KEY (plan_id, name)
        )""",
    )),
    Migration(7, "each candidate's fit score on the materials its job held out", (
        "ALTER TABLE candidates ADD COLUMN fit_score REAL",  # NULL: not scored (no held-out materials)
    )),
    Migration(8, "each DONE plan's stored files with their SHA-256, checked when read back", (
        "ALTER TABLE plans ADD COLUMN files TEXT",  # canonical JSON {name: sha256}; NULL before this version
    )),
    Migration(9, "why search.stop_when ended a search, a column of its last search round, out of extra", (
        "ALTER TABLE rounds ADD COLUMN stop_reason TEXT",  # NULL: stop_when did not end the search here
        # Stores written before this version kept it as the key stop_when of the round's extra JSON.
        """UPDATE rounds SET stop_reason = json_extract(extra, '$.stop_when'), extra = json_remove(extra, '$.stop_when')
           WHERE json_type(extra, '$.stop_when') = 'text'""",
    )),
    Migration(10, "each job's unfinished dataset preparations, a column instead of counted from its events", (
        "ALTER TABLE jobs ADD COLUMN unfinished_preparations INTEGER NOT NULL DEFAULT 0 "
        "CHECK (unfinished_preparations >= 0)",
        # Stores written before this version: the preparing events since the last that ended.
        """UPDATE jobs SET unfinished_preparations = (
               SELECT COUNT(*) FROM events e WHERE e.job_id = jobs.id AND e.kind = 'preparing' AND e.seq > COALESCE(
                   (SELECT MAX(f.seq) FROM events f WHERE f.job_id = jobs.id
                                                      AND f.kind IN ('dataset', 'preparation_interrupted')), 0))""",
    )),
    Migration(11, "each job's measured evaluation cost per state (search.cost: time), a table instead of its events", (
        """CREATE TABLE state_costs (
            job_id          TEXT    NOT NULL REFERENCES jobs(id) ON DELETE CASCADE,
            state           TEXT    NOT NULL,
            ns              REAL    NOT NULL CHECK (ns > 0),    -- nanoseconds per evaluation
            PRIMARY KEY (job_id, state)
        )""",
        # Stores written before this version: the cost events, the first of each state kept.
        """INSERT OR IGNORE INTO state_costs (job_id, state, ns)
           SELECT job_id, json_extract(payload, '$.state'), json_extract(payload, '$.ns') FROM events
           WHERE kind = 'cost' AND json_type(payload, '$.state') = 'text'
             AND json_type(payload, '$.ns') IN ('real', 'integer') AND json_extract(payload, '$.ns') > 0
           ORDER BY job_id, seq""",
    )),
)

SCHEMA_VERSION = MIGRATIONS[-1].version


def schema_version(conn: sqlite3.Connection) -> int:
    """The database's version (0 for a database without a ``schema_version`` table)."""
    has_table = conn.execute(
        "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'schema_version'").fetchone()
    if not has_table:
        return 0
    row = conn.execute("SELECT version FROM schema_version").fetchone()
    return 0 if row is None else int(row[0])


def migrate(conn: sqlite3.Connection, migrations: Sequence[Migration] = MIGRATIONS) -> int:
    """Bring the database up to the last of ``migrations``; returns the version it is now at.

    ``conn`` must be in autocommit mode (``isolation_level=None``): this function opens its own
    ``BEGIN IMMEDIATE`` transaction, which also serialises processes that open a new database at
    the same time (the second one finds it migrated). Raises ``SchemaVersionError`` for a database
    newer than the code.
    """
    for i, m in enumerate(migrations, start=1):
        if m.version != i:
            raise ValueError(f"migration #{i} has version {m.version}; versions must be 1, 2, 3, ...")
    latest = len(migrations)
    if _check(conn, latest) == latest:  # fast path: no write lock when up to date
        return latest
    conn.execute("BEGIN IMMEDIATE")
    try:
        current = _check(conn, latest)
        if current < latest:
            conn.execute("CREATE TABLE IF NOT EXISTS schema_version (version INTEGER NOT NULL)")
            for m in migrations[current:]:
                for statement in m.statements:
                    try:
                        conn.execute(statement)
                    except sqlite3.Error as exc:
                        raise StorageError(
                            f"schema migration {m.version} ({m.description}) failed: {exc}; the "
                            f"database is left unchanged at version {current}") from exc
            conn.execute("DELETE FROM schema_version")
            conn.execute("INSERT INTO schema_version (version) VALUES (?)", (latest,))
        conn.execute("COMMIT")
    except BaseException:
        if conn.in_transaction:
            conn.execute("ROLLBACK")
        raise
    return latest


def _check(conn: sqlite3.Connection, latest: int) -> int:
    current = schema_version(conn)
    if current > latest:
        raise SchemaVersionError(
            f"the job database has schema version {current}, but this neuenh only knows versions up "
            f"to {latest}: it was written by a newer neuenh. Upgrade neuenh (or use another "
            f"database file); the database was not modified.")
    return current
