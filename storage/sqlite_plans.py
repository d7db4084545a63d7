"""``PlanStore`` on the service's SQLite file (``storage.sqlite.SQLiteDatabase``: its schema,
connections and transaction policy), beside the job store."""

from __future__ import annotations

import json
import time
import uuid
from collections.abc import Mapping
from typing import Any

from .errors import ConflictError, InvalidRecordError, NotFoundError
from .jobs import canonical_json, stored_idempotency_key
from .plans import PlanRecord, PlanStatus, PlanStore, check_plan_transition
from .sqlite import SQLiteDatabase, owned_by_key


class SQLitePlanStore(SQLiteDatabase, PlanStore):
    def create_plan(self, scene: Mapping[str, Any], *, owner: str | None = None,
                    idempotency_key: str | None = None) -> tuple[PlanRecord, bool]:
        if not isinstance(scene, Mapping):
            raise InvalidRecordError(f"a scene is a JSON object (mapping), got {type(scene).__name__}")
        scene_json = canonical_json(dict(scene), "scene")
        stored_key = None if idempotency_key is None else stored_idempotency_key(idempotency_key, owner)
        now = time.time()
        with self._write("create plan") as c:
            if stored_key is not None:
                row = owned_by_key(c, "plans", stored_key, idempotency_key, owner)
                if row is not None:
                    if row["scene"] != scene_json:
                        raise ConflictError(f"idempotency key {idempotency_key!r} was already used for plan "
                                            f"{row['id']} with a different scene")
                    return _plan(c, row), False
            plan_id = uuid.uuid4().hex
            c.execute("INSERT INTO plans (id, scene, status, created_at, updated_at, owner, idempotency_key) "
                      "VALUES (?, ?, ?, ?, ?, ?, ?)",
                      (plan_id, scene_json, PlanStatus.QUEUED.value, now, now, owner, stored_key))
            return _plan(c, _require(c, plan_id)), True

    def get_plan(self, plan_id: str) -> PlanRecord:
        with self._read(f"get plan {plan_id}") as c:
            return _plan(c, _require(c, plan_id))

    def list_plans(self, *, owner: str | None = None, limit: int = 100) -> list[PlanRecord]:
        with self._read("list plans") as c:
            rows = c.execute("SELECT * FROM plans" + (" WHERE owner = ?" if owner is not None else "")
                             + " ORDER BY seq DESC LIMIT ?", (*([owner] if owner is not None else []), limit))
            return [_plan(c, r) for r in rows.fetchall()]

    def unfinished_plans(self) -> list[PlanRecord]:
        with self._read("list unfinished plans") as c:
            rows = c.execute("SELECT * FROM plans WHERE status IN (?, ?) ORDER BY seq",
                             (PlanStatus.QUEUED.value, PlanStatus.RUNNING.value)).fetchall()
            return [_plan(c, r) for r in rows]

    def start(self, plan_id: str, materials_total: int) -> PlanRecord:
        if materials_total < 0:
            raise InvalidRecordError(f"plan {plan_id}: materials_total must be >= 0, got {materials_total}")
        return self._move(plan_id, PlanStatus.RUNNING, materials_total=int(materials_total))

    def record_material(self, plan_id: str, name: str, result: Mapping[str, Any]) -> None:
        text = canonical_json(dict(result), f"plan {plan_id} material {name!r}")
        with self._write(f"record material {name!r} of plan {plan_id}") as c:
            if PlanStatus(_require(c, plan_id)["status"]) != PlanStatus.RUNNING:
                raise InvalidRecordError(f"plan {plan_id}: materials are recorded while it runs")
            order = c.execute("SELECT COALESCE(MAX(recorded), -1) + 1 FROM plan_materials WHERE plan_id = ?",
                              (plan_id,)).fetchone()[0]
            c.execute("INSERT OR IGNORE INTO plan_materials (plan_id, name, recorded, result) VALUES (?, ?, ?, ?)",
                      (plan_id, name, order, text))
            c.execute("UPDATE plans SET updated_at = ? WHERE id = ?", (time.time(), plan_id))

    def planned_materials(self, plan_id: str) -> dict[str, dict[str, Any]]:
        with self._read(f"planned materials of plan {plan_id}") as c:
            _require(c, plan_id)
            rows = c.execute("SELECT name, result FROM plan_materials WHERE plan_id = ? ORDER BY recorded",
                             (plan_id,)).fetchall()
        return {r["name"]: json.loads(r["result"]) for r in rows}

    def finish(self, plan_id: str, result: Mapping[str, Any], files: Mapping[str, str] | None = None) -> PlanRecord:
        return self._move(plan_id, PlanStatus.DONE, result=canonical_json(dict(result), f"plan {plan_id} result"),
                          files=canonical_json(dict(files or {}), f"plan {plan_id} files"))

    def fail(self, plan_id: str, error: str) -> PlanRecord:
        if not isinstance(error, str) or not error:
            raise InvalidRecordError(f"plan {plan_id}: a failure says why")
        return self._move(plan_id, PlanStatus.FAILED, error=error)

    def cancel(self, plan_id: str) -> PlanRecord:
        return self._move(plan_id, PlanStatus.CANCELLED)

    def _move(self, plan_id: str, status: PlanStatus, **columns) -> PlanRecord:
        with self._write(f"set status of plan {plan_id}") as c:
            check_plan_transition(plan_id, PlanStatus(_require(c, plan_id)["status"]), status)
            sets = ", ".join(f"{k} = ?" for k in ("status", "updated_at", *columns))
            c.execute(f"UPDATE plans SET {sets} WHERE id = ?", (status.value, time.time(), *columns.values(), plan_id))
            return _plan(c, _require(c, plan_id))


def _require(c, plan_id: str):
    row = c.execute("SELECT * FROM plans WHERE id = ?", (plan_id,)).fetchone()
    if row is None:
        raise NotFoundError(f"no plan {plan_id!r}")
    return row


def _plan(c, row) -> PlanRecord:
    done = c.execute("SELECT COUNT(*) FROM plan_materials WHERE plan_id = ?", (row["id"],)).fetchone()[0]
    return PlanRecord(id=row["id"], scene=json.loads(row["scene"]), status=PlanStatus(row["status"]),
                      created_at=row["created_at"], updated_at=row["updated_at"], owner=row["owner"],
                      error=row["error"], materials_total=row["materials_total"], materials_done=int(done),
                      result=json.loads(row["result"]) if row["result"] else None,
                      files=json.loads(row["files"]) if row["files"] else {})
