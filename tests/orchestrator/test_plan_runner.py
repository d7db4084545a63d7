"""``PlanRunner``: any exception while planning ends the plan FAILED with a one-line reason (issue 26,
case 2: torch's RuntimeError for ``fit.samples: 1e13`` escaped it, and the plan stayed RUNNING on
every restart)."""

from __future__ import annotations

import time

from data_files import tiny_rgl_fields, write_tensor_file
from neuenh_service.orchestrator.plans import PlanRunner
from neuenh_service.storage import LocalArtifactStore, PlanStatus, SQLitePlanStore


def test_any_exception_while_planning_fails_the_plan_with_its_reason(tmp_path):
    write_tensor_file(tmp_path / "tiny.bsdf", tiny_rgl_fields())
    store = SQLitePlanStore(tmp_path / "jobs.sqlite")
    plan, _ = store.create_plan({"materials": [{"path": str(tmp_path / "tiny.bsdf")}], "ladder": ["ggx"],
                                 "tolerance": {"relative": 0.1}, "fit": {"samples": 10**13}})
    start = time.monotonic()
    ended = PlanRunner(store, LocalArtifactStore(tmp_path / "artifacts")).run(plan.id)
    assert ended.status is PlanStatus.FAILED and store.unfinished_plans() == []
    assert "\n" not in ended.error and ended.error.split(":")[0] in ("RuntimeError", "MemoryError"), ended.error
    assert time.monotonic() - start < 60
    store.close()
