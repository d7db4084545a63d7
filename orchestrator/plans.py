"""Scene plans as a persisted job kind (issue 15): ``PlanRunner.run(plan_id)`` plans the stored scene
with ``neuenh.scene.plan_scene`` in this process, material by material.

    QUEUED -> RUNNING -> DONE | FAILED | CANCELLED

Each material's result is recorded in the ``PlanStore`` as it is planned, so a plan interrupted by
a stop or a crash resumes with the materials already planned and plans only the rest. When every
material is planned, the plan's files (``neuenh.scene.outputs``: plan.json, plan.md, the cost-against-
error plot, the contact sheet, and the bundles of the rungs it uses, zipped) go to the ArtifactStore
under ``plans/<id>/`` and the plan is DONE with its ``Plan.to_json`` and each file's SHA-256 in the
store. A scene that cannot be planned (a missing file, an unknown model) — or any other exception
while planning it — is FAILED with the one-line reason, so a plan never stays RUNNING to fail again
on every start (only a store that cannot record even that raises).

Paths in a stored scene are resolved against ``base`` (the service's working directory, as a job
spec's data paths); the API checks them against the data roots before a plan is stored.
"""

from __future__ import annotations

import io
import logging
import tempfile
import zipfile
from pathlib import Path
from typing import Callable

from neuenh.scene import MaterialPlan, SceneError, parse_scene, plan_scene
from neuenh.scene.outputs import write_plan
from neuenh.scene.planner import load_materials
from neuenh_service.storage import ArtifactStore, PlanRecord, PlanStore

log = logging.getLogger("neuenh.orchestrator.plans")

PLAN_FILES = ("plan.json", "plan.md", "cost_vs_error.png", "contact_sheet.png", "bundles.zip")
CONTENT_TYPES = {".json": "application/json", ".md": "text/markdown; charset=utf-8", ".png": "image/png",
                 ".zip": "application/zip"}


class PlanInterrupted(Exception):
    """The service is stopping: the plan stays RUNNING and resumes on the next start."""


def plan_file_key(plan_id: str, name: str) -> str:
    return f"plans/{plan_id}/{name}"


class PlanRunner:
    def __init__(self, plans: PlanStore, artifacts: ArtifactStore, *, base: Path | None = None,
                 should_stop: Callable[[], bool] = lambda: False,
                 on_progress: Callable[[str, str, int, int], None] | None = None,
                 max_materials: int | None = None):
        """``max_materials``: fail a scene with more materials once read (a capture counts each of its
        texels, which the scene alone does not tell)."""
        self.plans, self.artifacts = plans, artifacts
        self.base = base or Path.cwd()
        self.should_stop, self.on_progress = should_stop, on_progress
        self.max_materials = max_materials

    def run(self, plan_id: str) -> PlanRecord:
        record = self.plans.get_plan(plan_id)
        if record.terminal:
            return record
        try:
            spec = parse_scene(record.scene, "scene")
            count = len(load_materials(spec, self.base))
            if self.max_materials is not None and count > self.max_materials:
                raise SceneError(f"materials: the scene holds {count} materials (a capture counts each texel); "
                                 f"this service plans at most {self.max_materials} (NEUENH_MAX_MATERIALS)")
            self.plans.start(plan_id, count)
            done = {n: MaterialPlan.from_json(v) for n, v in self.plans.planned_materials(plan_id).items()}

            def progress(what: str, step: int, total: int) -> None:
                if self.on_progress:
                    self.on_progress(plan_id, what, step, total)
                if self.should_stop():
                    raise PlanInterrupted()

            plan = plan_scene(spec, self.base, done=done, progress=progress,
                              on_material=lambda m: self.plans.record_material(plan_id, m.name, m.to_json()))
            files = self._store_files(plan_id, plan)
            return self.plans.finish(plan_id, plan.to_json(), files)
        except PlanInterrupted:
            log.info("plan %s: interrupted; it resumes on the next start", plan_id)
            return self.plans.get_plan(plan_id)
        except Exception as exc:  # noqa: BLE001 - any failure ends the plan, never leaves it RUNNING
            expected = isinstance(exc, (SceneError, ValueError, OSError))
            log.log(logging.INFO if expected else logging.ERROR, "plan %s: failed", plan_id,
                    exc_info=None if expected else exc)
            return self.plans.fail(plan_id, reason(exc))

    def _store_files(self, plan_id: str, plan) -> dict[str, str]:
        """Write the plan's files to the artifact store; each one's SHA-256 by name."""
        digests = {}
        with tempfile.TemporaryDirectory(prefix="neuenh-plan-") as tmp:
            out = Path(tmp)
            write_plan(plan, out)
            for name in PLAN_FILES[:-1]:
                if (out / name).exists():
                    digests[name] = self.artifacts.put(plan_file_key(plan_id, name), (out / name).read_bytes())
            if (out / "bundles").is_dir():
                buffer = io.BytesIO()
                with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
                    for path in sorted((out / "bundles").rglob("*")):
                        if path.is_file():
                            archive.write(path, path.relative_to(out))
                digests["bundles.zip"] = self.artifacts.put(plan_file_key(plan_id, "bundles.zip"), buffer.getvalue())
        return digests


def reason(exc: BaseException) -> str:
    """A failure in one line: the message's first line (a user's mistake says what is wrong), with
    the exception's kind in front when it is not one of the expected ones (a bug, torch running out
    of memory, ...)."""
    first = str(exc).splitlines()[0].strip() if str(exc).strip() else ""
    if isinstance(exc, (SceneError, ValueError, OSError)) and first:
        return first
    return f"{type(exc).__name__}: {first}" if first else type(exc).__name__
