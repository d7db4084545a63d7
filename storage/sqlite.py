"""``JobStore`` on one SQLite file, with the standard library's ``sqlite3``.

* **WAL** journal: readers (the API's threads, another process) never block the writer and see
  the last committed transaction; ``synchronous=FULL`` so a committed round survives a power cut.
  WAL needs a local filesystem (not NFS), like SQLite itself.
* **One connection per thread**, opened lazily, all closed by ``close()``. Every write is a
  ``BEGIN IMMEDIATE`` transaction (it takes the write lock up front, so two writers queue on
  ``busy_timeout`` instead of failing on a lock upgrade); multi-statement reads run in one
  deferred transaction, i.e. on one snapshot.
* **Foreign keys** on; the schema is in ``storage.migrations`` and is upgraded when the store is
  opened (``SchemaVersionError`` for a database written by a newer neuenh).
* A store object belongs to the process that opened it: after ``fork`` open a new one.
"""

from __future__ import annotations

import dataclasses
import json
import os
import sqlite3
import threading
import time
import uuid
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from .errors import ConflictError, InvalidRecordError, NotFoundError, StorageError
from .jobs import (UNFINISHED, CandidateRecord, EventKind, EventRecord, FinishedCandidate,
                   HalvingRecord, JobPage, JobRecord, JobStatus, JobStore, RoundKind, RoundRecord, StoreStatistics,
                   WarmupRecord, caller_idempotency_key, candidate_payload, canonical_json, check_transition, round_payload,
                   status_filter, stored_idempotency_key, validate_charge, validate_error, validate_state_cost,
                   validate_preparation_end)
from .migrations import migrate

INT64_MAX = 2**63 - 1  # SQLite's largest integer: a larger bound is clamped to it, never sent as is


class SQLiteDatabase:
    """The SQLite file ``path`` (created, with its parent directory, if missing) at the latest schema,
    and the transaction policy of the module doc: ``_write`` and ``_read`` are the only ways in. The
    stores of the service (``SQLiteJobStore``, ``storage.sqlite_plans.SQLitePlanStore``) share it."""

    def __init__(self, path: str | os.PathLike, *, busy_timeout_s: float = 10.0) -> None:
        if str(path) == ":memory:" or str(path).startswith("file:"):
            raise ValueError(f"{type(self).__name__} needs a file path (each thread opens its own connection)")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._busy_timeout_s = float(busy_timeout_s)
        self._local = threading.local()
        self._connections: list[sqlite3.Connection] = []
        self._lock = threading.Lock()
        self._closed = False
        self._pid = os.getpid()
        try:
            migrate(self._conn())
        except sqlite3.Error as exc:
            self.close()
            raise StorageError(f"cannot open the job database {self.path}: {exc}") from exc
        except StorageError as exc:
            self.close()
            raise type(exc)(f"cannot open the job database {self.path}: {exc}") from exc.__cause__
        except BaseException:
            self.close()
            raise

    def check_integrity(self) -> None:
        """Raise ``StorageError`` (saying what to do) unless SQLite's quick_check finds the database
        intact; run at service start, so a damaged page is found before a job runs into it."""
        try:
            problems = [row[0] for row in self._conn().execute("PRAGMA quick_check").fetchall()]
        except sqlite3.DatabaseError as exc:
            problems = [str(exc)]
        if problems != ["ok"]:
            raise StorageError(f"the job database {self.path} is damaged ({'; '.join(problems[:3])}); stop the "
                               "service and restore it from a backup (docs/DEPLOY.md, 'Back up and restore')")

    # ---------------------------------------------------------------------------- connections

    def _conn(self) -> sqlite3.Connection:
        if self._closed:
            raise StorageError(f"the job store {self.path} is closed")
        if os.getpid() != self._pid:
            raise StorageError(f"a {type(self).__name__} cannot cross a fork; open a new one in this process")
        conn = getattr(self._local, "conn", None)
        if conn is None:
            conn = sqlite3.connect(self.path, timeout=self._busy_timeout_s, isolation_level=None,
                                   check_same_thread=False)  # still one thread each; close() may run anywhere
            conn.row_factory = sqlite3.Row
            conn.execute(f"PRAGMA busy_timeout = {int(self._busy_timeout_s * 1000)}")
            mode = conn.execute("PRAGMA journal_mode = WAL").fetchone()[0]
            if mode.lower() != "wal":
                conn.close()
                raise StorageError(f"{self.path}: cannot switch to WAL journal mode (got {mode!r})")
            conn.execute("PRAGMA foreign_keys = ON")
            conn.execute("PRAGMA synchronous = FULL")
            with self._lock:
                self._connections.append(conn)
            self._local.conn = conn
        return conn

    @contextmanager
    def _write(self, what: str) -> Iterator[sqlite3.Connection]:
        conn = self._conn()
        try:
            conn.execute("BEGIN IMMEDIATE")
            try:
                yield conn
                conn.execute("COMMIT")
            except BaseException:
                if conn.in_transaction:
                    conn.execute("ROLLBACK")
                raise
        except sqlite3.IntegrityError as exc:
            raise InvalidRecordError(f"{what}: rejected by the schema ({exc}); nothing was written") from exc
        except sqlite3.Error as exc:
            raise StorageError(f"{what}: {exc}") from exc

    @contextmanager
    def _read(self, what: str) -> Iterator[sqlite3.Connection]:
        conn = self._conn()
        try:
            conn.execute("BEGIN")
            try:
                yield conn
            finally:
                if conn.in_transaction:
                    conn.execute("COMMIT")
        except sqlite3.Error as exc:
            raise StorageError(f"{what}: {exc}") from exc

    def close(self) -> None:
        with self._lock:
            self._closed = True
            connections, self._connections = self._connections, []
        for conn in connections:
            conn.close()


class SQLiteJobStore(SQLiteDatabase, JobStore):
    """A ``JobStore`` in the SQLite file ``path`` (created, with its parent directory, if missing)."""

    # ----------------------------------------------------------------------------------- jobs

    def create_job(self, spec: Mapping[str, Any], *,
                   idempotency_key: str | None = None, owner: str | None = None) -> tuple[JobRecord, bool]:
        if not isinstance(spec, Mapping):
            raise InvalidRecordError(f"a job spec is a JSON object (mapping), got {type(spec).__name__}")
        spec_json = canonical_json(dict(spec), "job spec")
        stored_key = None if idempotency_key is None else stored_idempotency_key(idempotency_key, owner)
        now = time.time()
        with self._write("create job") as c:
            if stored_key is not None:
                row = owned_by_key(c, "jobs", stored_key, idempotency_key, owner)
                if row is not None:
                    if row["spec"] != spec_json:
                        raise ConflictError(f"idempotency key {idempotency_key!r} was already used for job "
                                            f"{row['id']} with a different spec")
                    return _job(row), False
            job_id = uuid.uuid4().hex
            c.execute("INSERT INTO jobs (id, spec, status, created_at, updated_at, idempotency_key, owner) "
                      "VALUES (?, ?, ?, ?, ?, ?, ?)",
                      (job_id, spec_json, JobStatus.QUEUED.value, now, now, stored_key, owner))
            _append(c, job_id, now, EventKind.STATUS,
                    {"status": JobStatus.QUEUED.value, "previous": None, "error": None})
        return JobRecord(id=job_id, spec=json.loads(spec_json), status=JobStatus.QUEUED,
                         created_at=now, updated_at=now, idempotency_key=idempotency_key, owner=owner), True

    def statistics(self) -> StoreStatistics:
        with self._read("statistics") as c:
            by_status = {JobStatus(r[0]): r[1] for r in c.execute("SELECT status, COUNT(*) FROM jobs GROUP BY status")}
            total, failed = c.execute("SELECT COUNT(*), COALESCE(SUM(error IS NOT NULL), 0) FROM candidates").fetchone()
            candidate_s = tuple(r[0] for r in c.execute("SELECT wall_s FROM candidates"))
            round_s = tuple(r[0] for r in c.execute("SELECT finished_at - started_at FROM rounds"))
        return StoreStatistics(by_status, int(total), int(failed), candidate_s, round_s)

    def get_job(self, job_id: str) -> JobRecord:
        with self._read(f"get job {job_id}") as c:
            return _job(_require(c, job_id))

    def list_jobs(self, *, status: JobStatus | Iterable[JobStatus] | None = None,
                  limit: int = 50, cursor: str | None = None, owner: str | None = None) -> JobPage:
        if not isinstance(limit, int) or limit < 1:
            raise InvalidRecordError(f"limit must be a positive integer, got {limit!r}")
        try:
            statuses = status_filter(status)
        except ValueError as exc:
            raise InvalidRecordError(f"unknown job status in {status!r}") from exc
        where, args = [], []
        if statuses is not None:
            where.append(f"status IN ({', '.join('?' * len(statuses))})")
            args += [s.value for s in statuses]
        if owner is not None:
            where.append("owner = ?")
            args.append(owner)
        if cursor is not None:
            try:
                before = int(cursor)
            except (TypeError, ValueError):
                raise InvalidRecordError(f"invalid cursor {cursor!r}") from None
            where.append("seq < ?")
            args.append(min(before, INT64_MAX))  # SQLite's integers are int64: every seq is below
        sql = "SELECT * FROM jobs" + (" WHERE " + " AND ".join(where) if where else "")
        with self._read("list jobs") as c:
            rows = c.execute(sql + " ORDER BY seq DESC LIMIT ?", (*args, limit + 1)).fetchall()
        more = len(rows) > limit
        rows = rows[:limit]
        return JobPage(jobs=tuple(_job(r) for r in rows),
                       next_cursor=str(rows[-1]["seq"]) if more else None)

    def unfinished_jobs(self) -> list[JobRecord]:
        names = sorted(s.value for s in UNFINISHED)
        with self._read("list unfinished jobs") as c:
            rows = c.execute(f"SELECT * FROM jobs WHERE status IN ({', '.join('?' * len(names))}) "
                             "ORDER BY seq", names).fetchall()
        return [_job(r) for r in rows]

    def set_status(self, job_id: str, status: JobStatus, *, error: str | None = None,
                   reason: str | None = None) -> JobRecord:
        try:
            status = JobStatus(status)
        except ValueError:
            raise InvalidRecordError(f"unknown job status {status!r}") from None
        validate_error(job_id, status, error, reason)
        now = time.time()
        with self._write(f"set status of job {job_id}") as c:
            old = JobStatus(_require(c, job_id)["status"])
            check_transition(job_id, old, status)
            c.execute("UPDATE jobs SET status = ?, error = ?, reason = ?, updated_at = ? WHERE id = ?",
                      (status.value, error, reason, now, job_id))
            _append(c, job_id, now, EventKind.STATUS,
                    {"status": status.value, "previous": old.value, "error": error,
                     **({"reason": reason} if reason is not None else {})})
            return _job(_require(c, job_id))

    def begin_preparation(self, job_id: str) -> JobRecord:
        now = time.time()
        with self._write(f"begin preparing job {job_id}") as c:
            _require(c, job_id)
            c.execute("UPDATE jobs SET unfinished_preparations = unfinished_preparations + 1 WHERE id = ?", (job_id,))
            _append(c, job_id, now, EventKind.PREPARING, {})
            return _job(_require(c, job_id))

    def end_preparation(self, job_id: str, kind: EventKind, payload: Mapping[str, Any] | None = None) -> JobRecord:
        kind = validate_preparation_end(job_id, kind)
        payload = json.loads(canonical_json(dict(payload or {}), f"{kind} event payload"))
        now = time.time()
        with self._write(f"end preparing job {job_id}") as c:
            _require(c, job_id)
            c.execute("UPDATE jobs SET unfinished_preparations = 0 WHERE id = ?", (job_id,))
            _append(c, job_id, now, kind, payload)
            return _job(_require(c, job_id))

    def record_state_cost(self, job_id: str, state: str, ns: float) -> float:
        ns = validate_state_cost(job_id, state, ns)
        now = time.time()
        with self._write(f"record state {state}'s cost for job {job_id}") as c:
            _require(c, job_id)
            kept = c.execute("SELECT ns FROM state_costs WHERE job_id = ? AND state = ?", (job_id, state)).fetchone()
            if kept is not None:
                return kept["ns"]
            c.execute("INSERT INTO state_costs (job_id, state, ns) VALUES (?, ?, ?)", (job_id, state, ns))
            _append(c, job_id, now, EventKind.COST, {"state": state, "ns": ns})
            return ns

    def state_costs(self, job_id: str) -> dict[str, float]:
        with self._read(f"read state costs of job {job_id}") as c:
            _require(c, job_id)
            rows = c.execute("SELECT state, ns FROM state_costs WHERE job_id = ?", (job_id,)).fetchall()
        return {r["state"]: r["ns"] for r in rows}

    def charge(self, job_id: str, *, wall_s: float = 0.0, cpu_s: float = 0.0) -> JobRecord:
        wall_s, cpu_s = validate_charge(job_id, wall_s, cpu_s)
        with self._write(f"charge job {job_id}") as c:
            _require(c, job_id)
            return _charge(c, job_id, wall_s, cpu_s)

    # ---------------------------------------------------------------------- finished candidates

    def record_candidate(self, job_id: str, finished: FinishedCandidate, *, wall_s: float = 0.0,
                         cpu_s: float = 0.0) -> JobRecord:
        if not isinstance(finished, FinishedCandidate):
            raise TypeError(f"record_candidate takes a FinishedCandidate, got {type(finished).__name__}")
        wall_s, cpu_s = validate_charge(job_id, wall_s, cpu_s)
        record = canonical_json(dataclasses.asdict(finished.candidate), "finished candidate")
        state, i = finished.candidate.state, finished.round_index
        now = time.time()
        with self._write(f"record candidate {state} of round {i} of job {job_id}") as c:
            job = _require(c, job_id)
            stored = c.execute("SELECT record, artifact_key FROM finished_candidates WHERE job_id = ? AND "
                               "round_index = ? AND phase = ? AND state = ?",
                               (job_id, i, finished.phase, state)).fetchone()
            if stored is not None:
                if (stored["record"], stored["artifact_key"]) != (record, finished.artifact_key):
                    raise ConflictError(f"job {job_id}: candidate {state} ({finished.phase}) of round {i} is "
                                        "already recorded with different content")
                return _job(job)
            order = c.execute("SELECT COALESCE(MAX(recorded), 0) + 1 FROM finished_candidates WHERE job_id = ?",
                              (job_id,)).fetchone()[0]
            c.execute("INSERT INTO finished_candidates (job_id, round_index, phase, state, recorded, record, "
                      "artifact_key) VALUES (?, ?, ?, ?, ?, ?, ?)",
                      (job_id, i, finished.phase, state, order, record, finished.artifact_key))
            charged = _charge(c, job_id, wall_s, cpu_s)
            _append(c, job_id, now, EventKind.CANDIDATE, candidate_payload(finished))
            return charged

    def finished_candidates(self, job_id: str, round_index: int) -> list[FinishedCandidate]:
        with self._read(f"read finished candidates of job {job_id}") as c:
            _require(c, job_id)
            rows = c.execute("SELECT * FROM finished_candidates WHERE job_id = ? AND round_index = ? "
                             "ORDER BY recorded", (job_id, int(round_index))).fetchall()
        return [FinishedCandidate(round_index=r["round_index"], phase=r["phase"],
                                  candidate=CandidateRecord(**json.loads(r["record"])),
                                  artifact_key=r["artifact_key"]) for r in rows]

    # --------------------------------------------------------------------------------- rounds

    def commit_round(self, job_id: str, record: RoundRecord) -> RoundRecord:
        if not isinstance(record, RoundRecord):
            raise TypeError(f"commit_round takes a RoundRecord, got {type(record).__name__}")
        i = record.index
        now = time.time()
        with self._write(f"commit round {i} of job {job_id}") as c:
            job = _job(_require(c, job_id))
            if job.last_round is not None and i <= job.last_round:
                stored = _load_rounds(c, job_id, since=i, until=i)[0]
                if stored == record:
                    return stored
                raise ConflictError(f"job {job_id}: round {i} is already committed with different content")
            if job.status is not JobStatus.RUNNING:
                raise ConflictError(f"job {job_id} is {job.status.value}; rounds are committed only "
                                    f"while it is RUNNING")
            if i != job.next_round:
                raise ConflictError(f"job {job_id}: the next round to commit is {job.next_round}, not {i}")
            if job.current_state is not None and record.parent_state != job.current_state:
                raise ConflictError(f"job {job_id}: round {i} starts from {record.parent_state}, but the "
                                    f"current state is {job.current_state}")
            c.execute("INSERT INTO rounds (job_id, round_index, parent_state, winner_state, "
                      "winner_val_loss, started_at, finished_at, artifact_key, kind, outcome, warmup, "
                      "halving, recovered, stop_reason, extra) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                      (job_id, i, record.parent_state, record.winner_state, record.winner_val_loss,
                       record.started_at, record.finished_at, record.artifact_key, record.kind.value,
                       record.outcome.value if record.outcome else None,
                       _json_or_null(record.warmup, "round warmup"), _json_or_null(record.halving, "round halving"),
                       record.recovered, record.stop_reason, canonical_json(record.extra, "round extra")))
            for position, cand in enumerate(record.candidates):
                c.execute("INSERT INTO candidates (job_id, round_index, position, state, train_loss, "
                          "val_loss, epochs, wall_s, node, error, seed, pruned, extra, fit_score) "
                          "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                          (job_id, i, position, cand.state, cand.train_loss, cand.val_loss,
                           cand.epochs, cand.wall_s, cand.node, cand.error, cand.seed, int(cand.pruned),
                           canonical_json(cand.extra, "candidate extra"), cand.fit_score))
            c.execute("UPDATE jobs SET last_round = ?, current_state = ?, updated_at = ? WHERE id = ?",
                      (i, record.winner_state, now, job_id))
            _append(c, job_id, now, EventKind.ROUND, round_payload(record))
        return record

    def rounds(self, job_id: str, *, since_round: int = 0, until_round: int | None = None) -> list[RoundRecord]:
        with self._read(f"read rounds of job {job_id}") as c:
            _require(c, job_id)
            until = None if until_round is None else min(int(until_round), INT64_MAX)
            return _load_rounds(c, job_id, since=min(int(since_round), INT64_MAX), until=until)

    def last_round(self, job_id: str) -> RoundRecord | None:
        with self._read(f"read the last round of job {job_id}") as c:
            last = _require(c, job_id)["last_round"]
            if last is None:
                return None
            return _load_rounds(c, job_id, since=last, until=last)[0]

    # --------------------------------------------------------------------------------- events

    def append_event(self, job_id: str, kind: EventKind | str,
                     payload: Mapping[str, Any] | None = None) -> EventRecord:
        if not isinstance(kind, str) or not kind:
            raise InvalidRecordError("an event kind must be a non-empty string")
        payload = json.loads(canonical_json(dict(payload or {}), f"{kind} event payload"))
        now = time.time()
        with self._write(f"append a {kind} event to job {job_id}") as c:
            _require(c, job_id)
            seq = _append(c, job_id, now, kind, payload)
        return EventRecord(job_id=job_id, seq=seq, time=now, kind=kind, payload=payload)

    def events(self, job_id: str, *, after_seq: int = 0, limit: int | None = None) -> list[EventRecord]:
        if limit is not None and (not isinstance(limit, int) or limit < 1):
            raise InvalidRecordError(f"limit must be a positive integer or None, got {limit!r}")
        with self._read(f"read events of job {job_id}") as c:
            _require(c, job_id)
            rows = c.execute("SELECT * FROM events WHERE job_id = ? AND seq > ? ORDER BY seq LIMIT ?",
                             (job_id, int(after_seq), -1 if limit is None else limit)).fetchall()
        return [EventRecord(job_id=r["job_id"], seq=r["seq"], time=r["time"], kind=r["kind"],
                            payload=json.loads(r["payload"])) for r in rows]


# ---------------------------------------------------------------------------------- row helpers


def _require(c: sqlite3.Connection, job_id: str) -> sqlite3.Row:
    row = c.execute("SELECT * FROM jobs WHERE id = ?", (job_id,)).fetchone()
    if row is None:
        raise NotFoundError(f"no job {job_id!r}")
    return row


def _job(row: sqlite3.Row) -> JobRecord:
    return JobRecord(id=row["id"], spec=json.loads(row["spec"]), status=JobStatus(row["status"]),
                     created_at=row["created_at"], updated_at=row["updated_at"], error=row["error"],
                     idempotency_key=caller_idempotency_key(row["idempotency_key"]), last_round=row["last_round"],
                     current_state=row["current_state"], owner=row["owner"], reason=row["reason"],
                     used_wall_s=row["used_wall_s"], used_cpu_s=row["used_cpu_s"],
                     unfinished_preparations=row["unfinished_preparations"])


def owned_by_key(c: sqlite3.Connection, table: str, stored_key: str, key: str, owner: str | None):
    """The row of ``table`` (jobs or plans) that ``owner`` created under ``key``: stored scoped by
    its owner, or unscoped by a store written before keys were (then only the same owner's)."""
    return c.execute(f"SELECT * FROM {table} WHERE idempotency_key IN (?, ?) AND owner IS ?",
                     (stored_key, key, owner)).fetchone()


def _charge(c: sqlite3.Connection, job_id: str, wall_s: float, cpu_s: float) -> JobRecord:
    """Add validated seconds to the job's usage inside the caller's write transaction."""
    c.execute("UPDATE jobs SET used_wall_s = used_wall_s + ?, used_cpu_s = used_cpu_s + ? WHERE id = ?",
              (wall_s, cpu_s, job_id))
    return _job(_require(c, job_id))


def _append(c: sqlite3.Connection, job_id: str, now: float, kind: str, payload: Any) -> int:
    """Append an event inside the caller's write transaction (which serialises ``seq``)."""
    seq = c.execute("SELECT COALESCE(MAX(seq), 0) + 1 FROM events WHERE job_id = ?",
                    (job_id,)).fetchone()[0]
    c.execute("INSERT INTO events (job_id, seq, time, kind, payload) VALUES (?, ?, ?, ?, ?)",
              (job_id, seq, now, kind, canonical_json(payload, f"{kind} event payload")))
    return seq


def _load_rounds(c: sqlite3.Connection, job_id: str, since: int,
                 until: int | None = None) -> list[RoundRecord]:
    bound = "" if until is None else " AND round_index <= ?"
    args = (job_id, since) if until is None else (job_id, since, until)
    rounds = c.execute("SELECT * FROM rounds WHERE job_id = ? AND round_index >= ?" + bound +
                       " ORDER BY round_index", args).fetchall()
    by_round: dict[int, list[CandidateRecord]] = {r["round_index"]: [] for r in rounds}
    for r in c.execute("SELECT * FROM candidates WHERE job_id = ? AND round_index >= ?" + bound +
                       " ORDER BY round_index, position", args):
        by_round[r["round_index"]].append(CandidateRecord(
            state=r["state"], train_loss=r["train_loss"], val_loss=r["val_loss"], epochs=r["epochs"],
            wall_s=r["wall_s"], node=r["node"], error=r["error"], seed=r["seed"], pruned=bool(r["pruned"]),
            extra=json.loads(r["extra"]), fit_score=r["fit_score"]))
    return [RoundRecord(index=r["round_index"], parent_state=r["parent_state"],
                        winner_state=r["winner_state"], candidates=tuple(by_round[r["round_index"]]),
                        started_at=r["started_at"], finished_at=r["finished_at"],
                        artifact_key=r["artifact_key"], kind=RoundKind(r["kind"]),
                        outcome=JobStatus(r["outcome"]) if r["outcome"] else None,
                        warmup=WarmupRecord(**json.loads(r["warmup"])) if r["warmup"] else None,
                        halving=HalvingRecord(**json.loads(r["halving"])) if r["halving"] else None,
                        recovered=r["recovered"], stop_reason=r["stop_reason"], extra=json.loads(r["extra"]))
            for r in rounds]


def _json_or_null(record: Any, what: str) -> str | None:
    """A typed sub-record as canonical JSON (a dataclass's fields), or NULL."""
    return None if record is None else canonical_json(dataclasses.asdict(record), what)
