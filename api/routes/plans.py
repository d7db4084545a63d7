"""``/v1/plans``: plan a scene on the service (``neuenh.scene``; ``orchestrator.plans``) — per material
the cheapest rung of a ladder within a tolerance — follow it, and download its files.

The scene is the JSON form of ``scene.yaml``; its files (measured materials, captures, bundle folders
of the ladder) are paths the service reads, relative to its working directory, and must lie under
its data roots (``NEUENH_DATA_ROOTS``), as a job's data do. ``POST /v1/plan-uploads`` takes the
scene with the measured files themselves instead (multipart): a material whose path is an uploaded
file's name is that file, kept under the data directory by its content's digest (responses name it
``uploads/<sha256>``, never by the server's own path). A scene over the service's limits (the jobs'
``NEUENH_MAX_*`` settings, ``NEUENH_MAX_RENDER_SIZE``) is refused with 422 naming the setting. Plans
run one at a time beside the jobs, each in a process of its own (``api.plan_queue``), survive
restarts material by material, and can be cancelled (``POST /v1/plans/{id}/cancel``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from fastapi import APIRouter, Body, File, Form, Header, HTTPException, Response, UploadFile, status

from neuenh.data.measured import load_measured
from neuenh.data.table import load_table
from neuenh.files import existing
from neuenh.scene import SceneError, SceneSpec, parse_scene
from neuenh.scene.spec import CaptureEntry, FileEntry, ladder_source, scene_data
from neuenh_service.orchestrator.plans import CONTENT_TYPES, PLAN_FILES, plan_file_key
from neuenh_service.storage import ArtifactStore, CorruptArtifactError, PlanRecord, PlanStatus
from neuenh_service.storage.artifacts import sha256

from ..auth import LOCAL
from ..deps import (ArtifactStoreDep, Authorized, ChangeablePlan, FitLockDep, PlanQueueDep, PlanStoreDep,
                    PrincipalDep, SettingsDep, SubmitterDep, VisiblePlan, fit_slot)
from ..downloads import file_response
from ..errors import COMMON, DAMAGED, documented
from ..limits import path_problem, plan_problems
from ..schemas import PlanList, PlanPublic
from ..settings import Settings
from ..uploads import PLAN_UPLOADS, Received, discard, receive, uploaded_kind

router = APIRouter(prefix="/plans", tags=["plans"], dependencies=[Authorized], responses=COMMON)
# A scene with its files: a path of its own (under /plans it would also read as GET /plans/{plan_id}).
uploads = APIRouter(prefix="/plan-uploads", tags=["plans"], dependencies=[Authorized], responses=COMMON)

_ERRORS = documented({404: "no such plan"})


@router.post("", status_code=status.HTTP_202_ACCEPTED, response_model=PlanPublic,
             responses={200: {"model": PlanPublic, "description": "the plan already submitted under this Idempotency-Key"},
                        **documented({400: "a body that is not JSON", 409: "Idempotency-Key reused for another scene",
                                      422: "an invalid scene, or files outside the data roots"})})
def submit_plan(spec: Annotated[SceneSpec, Body(description="a scene (the JSON form of scene.yaml)")],
                response: Response, plans: PlanStoreDep, plan_queue: PlanQueueDep, settings: SettingsDep,
                principal: SubmitterDep,
                idempotency_key: Annotated[str | None, Header(max_length=200)] = None) -> PlanPublic:
    """Validate and queue a plan (202)."""
    return _queue(spec, set(), response, plans, plan_queue, settings, principal, idempotency_key)


def _parsed(data: object) -> SceneSpec:
    try:
        return parse_scene(data, "scene")
    except SceneError as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc)) from None


@uploads.post("", status_code=status.HTTP_202_ACCEPTED, response_model=PlanPublic,
             responses={200: {"model": PlanPublic, "description": "the plan already submitted under this Idempotency-Key"},
                        **documented({400: "a body that is not multipart/form-data",
                                      409: "Idempotency-Key reused for another scene",
                                      413: "upload over NEUENH_MAX_UPLOAD_BYTES",
                                      422: "an invalid scene, an unreadable or unnamed upload, or other files "
                                           "outside the data roots",
                                      429: "another fit or upload is running: retry after Retry-After seconds"})})
def submit_plan_with_files(
    response: Response, plans: PlanStoreDep, plan_queue: PlanQueueDep, settings: SettingsDep,
    principal: SubmitterDep, fit_lock: FitLockDep,
    scene: Annotated[str, Form(description="the scene: scene.yaml's text (YAML or JSON); a material whose "
                                           "path is an uploaded file's name is that file")],
    files: Annotated[list[UploadFile], File(description="measured materials the scene names: tables (.npz, CSV), "
                                                        "RGL .bsdf or MERL .binary files")],
    idempotency_key: Annotated[str | None, Header(max_length=200)] = None,
) -> PlanPublic:
    """Validate the scene and its files, keep the files, and queue the plan (202)."""
    try:
        data = scene_data(scene, "scene")
    except SceneError as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc)) from None
    # the scene's own limits before any file is read (the files' sizes count once they are kept)
    _check_limits(_parsed(data), settings)
    # One at a time: reading uploads costs memory like a fit, and a refused request removes the files
    # it alone kept, which a concurrent request with the same content must not see vanish.
    with fit_slot(fit_lock):
        received = receive(files, (settings.data_dir / PLAN_UPLOADS).resolve(),
                           lambda path, name: _check_measured(path, name, settings.max_samples), settings.max_samples)
        try:
            data, uploaded = _with_uploads(data, received)
            queued = _queue(_parsed(data), uploaded, response, plans, plan_queue, settings, principal,
                            idempotency_key)
            if response.status_code == status.HTTP_200_OK:  # found under its key: that plan has its files
                discard(received)
            return queued
        except BaseException:
            discard(received)
            raise


def _check_measured(path: Path, name: str, max_rows: int) -> str:
    """The kind of an uploaded measured file, after reading it whole (a table: refused from its row
    count before any value is read)."""
    kind = uploaded_kind(path)
    if kind == "table":
        load_table(path, name, max_rows)
    else:
        load_measured(path, name)
    return kind


def _with_uploads(data: dict, received: list[Received]) -> tuple[dict, set[str]]:
    """The scene with each material whose path names an upload pointing at the kept file (its name
    kept too), and the paths so set; an upload no material names is a 422."""
    by_name = {r.filename: r for r in received}
    used, uploaded, materials = set(), set(), []
    for entry in data.get("materials") or []:
        path = entry.get("path") if isinstance(entry, dict) else None
        upload = by_name.get(Path(path).name) if isinstance(path, str) and path else None
        if upload is not None:
            entry = {**entry, "path": str(upload.path), "sha256": upload.path.name,  # checked when read
                     "name": entry.get("name") or Path(path).stem}
            used.add(upload.filename)
            uploaded.add(str(upload.path))
        materials.append(entry)
    unnamed = sorted(set(by_name) - used)
    if unnamed:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"files: {', '.join(unnamed)} uploaded but named by no material's path")
    return ({**data, "materials": materials} if "materials" in data else data), uploaded


def _check_limits(spec: SceneSpec, settings: Settings) -> None:
    problems = plan_problems(spec, settings, Path.cwd())
    if problems:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, "scene refused: " + "; ".join(problems))


def _queue(spec: SceneSpec, uploaded: set[str], response: Response, plans, plan_queue, settings: Settings,
           principal, idempotency_key: str | None) -> PlanPublic:
    """Check the scene's other files against the data roots and the scene against the service's
    limits, then create (or find) and queue the plan."""
    outside = _outside_data_roots(spec, settings, uploaded)
    if outside:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, "; ".join(outside))
    _check_limits(spec, settings)
    plan, created = plans.create_plan(spec.model_dump(mode="json", exclude_none=True),
                                      owner=None if principal is LOCAL else principal.name,
                                      idempotency_key=idempotency_key)
    if created:
        plan_queue.enqueue(plan.id)
    else:
        response.status_code = status.HTTP_200_OK
    response.headers["Location"] = f"/v1/plans/{plan.id}"
    return _public(plan, [], plan_queue, settings)


def _public(plan: PlanRecord, files: list[str], plan_queue, settings: Settings) -> PlanPublic:
    """The plan as answered: the service's upload folder named ``uploads/``, never by its path."""
    return PlanPublic.from_record(plan, files, progress=plan_queue.progress(plan.id),
                                  hidden=_uploads_folder(settings))


def _uploads_folder(settings: Settings) -> Path:
    return (settings.data_dir / PLAN_UPLOADS).resolve()


@router.get("", response_model=PlanList)
def list_plans(plans: PlanStoreDep, plan_queue: PlanQueueDep, artifacts: ArtifactStoreDep, settings: SettingsDep,
               principal: PrincipalDep) -> PlanList:
    """Plans, newest first (a submit token sees its own)."""
    found = plans.list_plans(owner=None if principal.sees_all else principal.name)
    return PlanList(plans=[_public(p, _files(p, artifacts), plan_queue, settings) for p in found])


@router.get("/{plan_id}", response_model=PlanPublic, responses=_ERRORS)
def get_plan(plan: VisiblePlan, plan_queue: PlanQueueDep, artifacts: ArtifactStoreDep,
             settings: SettingsDep) -> PlanPublic:
    return _public(plan, _files(plan, artifacts), plan_queue, settings)


@router.post("/{plan_id}/cancel", response_model=PlanPublic, responses={
    **_ERRORS, **documented({403: "a read token, or another owner's plan", 409: "the plan has already ended"})})
def cancel_plan(plan: ChangeablePlan, plan_queue: PlanQueueDep, settings: SettingsDep) -> PlanPublic:
    """Cancel a queued or running plan: a running one's process is ended at once. The materials it
    planned stay recorded; files sent with it are released."""
    if plan.terminal:
        raise HTTPException(status.HTTP_409_CONFLICT,
                            f"plan {plan.id} is already {plan.status.value}; only unfinished plans can be cancelled")
    return _public(plan_queue.cancel(plan.id), [], plan_queue, settings)  # a lost race (it ended) is 409 too


@router.get("/{plan_id}/files/{name}", response_class=Response, responses={
    **_ERRORS, **DAMAGED, **file_response("one file of a DONE plan", *CONTENT_TYPES.values())})
def plan_file(plan: VisiblePlan, name: str, artifacts: ArtifactStoreDep, settings: SettingsDep) -> Response:
    """One of the plan's files: plan.json, plan.md, cost_vs_error.png, contact_sheet.png, bundles.zip,
    checked against the SHA-256 recorded when the plan finished."""
    if name not in PLAN_FILES:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"a plan has no file {name!r}; it has {', '.join(PLAN_FILES)}")
    key = plan_file_key(plan.id, name)
    if plan.status is not PlanStatus.DONE or not artifacts.exists(key):
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"plan {plan.id} has no {name}"
                            + ("" if plan.status is PlanStatus.DONE else f" yet (status {plan.status.value})"))
    data = artifacts.get(key)
    expected = plan.files.get(name)  # plans finished before digests were recorded have none
    if expected is not None and (actual := sha256(data)) != expected:
        raise CorruptArtifactError(f"artifact {key!r} is corrupt: its SHA-256 is {actual[:12]}..., plan {plan.id} "
                                   f"recorded {expected[:12]}...")
    if Path(name).suffix in (".json", ".md"):  # they quote the scene: name uploads as the responses do
        data = data.replace(f"{_uploads_folder(settings)}/".encode(), f"{PLAN_UPLOADS}/".encode())
    return Response(data, media_type=CONTENT_TYPES[Path(name).suffix],
                    headers={"Content-Disposition": f'inline; filename="{name}"'})


def _files(plan: PlanRecord, artifacts: ArtifactStore) -> list[str]:
    if plan.status is not PlanStatus.DONE:
        return []
    if plan.files:
        return [name for name in PLAN_FILES if name in plan.files]
    return [name for name in PLAN_FILES if artifacts.exists(plan_file_key(plan.id, name))]


def _outside_data_roots(spec, settings: Settings, uploaded: set[str] = frozenset()) -> list[str]:
    """Why the scene must not name the files and folders it would read (``limits.path_problem``: outside
    the data roots, or not a usable path). Ladder entries that are not paths (model names) read nothing
    of the user's; ``uploaded`` files were put where they are by the service."""
    paths = [(f"materials.{i}", e.path if isinstance(e, FileEntry) else e.capture)
             for i, e in enumerate(spec.materials) if isinstance(e, (FileEntry, CaptureEntry))]
    paths += [(f"ladder.{i}", ladder_source(e)) for i, e in enumerate(spec.ladder)]
    problems = []
    for where, path in paths:
        if path in uploaded:
            continue
        if where.startswith("ladder") and "/" not in path and existing(path) is None:
            continue  # a model's name (or no usable name at all: building the ladder says so)
        if (problem := path_problem(where, path, settings)) is not None:
            problems.append(problem)
    return problems
