"""``/v1/jobs``: submit a search job, list jobs, follow one (status, history), cancel it, download
its model."""

from __future__ import annotations

import io
import tempfile
import zipfile
from pathlib import Path
from typing import Annotated, Literal

from fastapi import APIRouter, Header, HTTPException, Query, Response, status

from neuenh.checkpoint import Bundle
from neuenh_service.storage import JobStatus, RoundRecord

from ..auth import LOCAL
from ..deps import (ArtifactStoreDep, Authorized, ChangeableJob, JobQueueDep, JobStoreDep, PrincipalDep,
                    SettingsDep, SubmitterDep, VisibleJob)
from ..downloads import file_response
from ..errors import COMMON, DAMAGED, documented
from ..limits import check_limits
from ..schemas import HistoryPublic, JobCreate, JobList, JobPublic

router = APIRouter(prefix="/jobs", tags=["jobs"], dependencies=[Authorized], responses=COMMON)

_ERRORS = documented({404: "no such job"})
MAX_EXPORTED = 64  # materials one export request may ask for (the files of each are written and zipped)
INT64_MAX = 2**63 - 1  # the store's integers are SQLite's: a cursor or round index beyond is a 422


@router.post("", status_code=status.HTTP_202_ACCEPTED, response_model=JobPublic,
             responses={200: {"model": JobPublic, "description": "the job already submitted under this Idempotency-Key"},
                        **documented({400: "a body that is not JSON",
                                      409: "Idempotency-Key reused for a different spec",
                                      413: "request body over NEUENH_MAX_REQUEST_BYTES",
                                      422: "invalid job spec, or over the service's limits"})})
def submit_job(spec: JobCreate, response: Response, settings: SettingsDep, job_queue: JobQueueDep,
               principal: SubmitterDep,
               idempotency_key: Annotated[str | None, Header(max_length=200)] = None) -> JobPublic:
    """Validate and queue a job (202). A repeated ``Idempotency-Key`` with the same spec returns
    the job it created (200)."""
    if "gpus_per_candidate" not in spec.resources.model_fields_set and settings.default_gpus_per_candidate:
        # stored explicitly, so the job runs the same wherever and whenever it resumes
        spec.resources.gpus_per_candidate = settings.default_gpus_per_candidate
    for field, default in (("wall_s", settings.default_budget_wall_s), ("cpu_s", settings.default_budget_cpu_s)):
        if default is not None and field not in spec.budget.model_fields_set:  # stored: it survives restarts
            setattr(spec.budget, field, default)
    check_limits(spec, settings, job_queue.orchestrator.executor.cluster())
    owner = None if principal is LOCAL else principal.name
    job, created = job_queue.orchestrator.submit(spec, idempotency_key=idempotency_key, owner=owner)
    if created:
        job_queue.enqueue(job)
    else:
        response.status_code = status.HTTP_200_OK
    public = JobPublic.from_record(job, progress=job_queue.progress(job.id))
    response.headers["Location"] = public.links.self
    return public


@router.get("", response_model=JobList)
def list_jobs(jobs: JobStoreDep, job_queue: JobQueueDep, principal: PrincipalDep,
              status_: Annotated[list[JobStatus] | None, Query(alias="status", description="repeat for several")] = None,
              limit: Annotated[int, Query(ge=1, le=500)] = 50,
              cursor: Annotated[int | None, Query(ge=0, le=INT64_MAX, description="next_cursor of the previous page")] = None) -> JobList:
    """Jobs, newest first, in pages (a submit token sees its own)."""
    page = jobs.list_jobs(status=status_ or None, limit=limit, cursor=None if cursor is None else str(cursor),
                          owner=None if principal.sees_all else principal.name)
    return JobList(jobs=[JobPublic.from_record(j, progress=job_queue.progress(j.id)) for j in page.jobs],
                   next_cursor=page.next_cursor)


@router.get("/{job_id}", response_model=JobPublic, responses=_ERRORS)
def get_job(job: VisibleJob, job_queue: JobQueueDep) -> JobPublic:
    return JobPublic.from_record(job, progress=job_queue.progress(job.id))


@router.get("/{job_id}/history", response_model=HistoryPublic, responses=_ERRORS)
def job_history(job: VisibleJob, jobs: JobStoreDep,
                since_round: Annotated[int, Query(ge=0, le=INT64_MAX)] = 0) -> HistoryPublic:
    """Committed rounds with index >= ``since_round``, each with every candidate and the winner."""
    job_id = job.id
    rounds = jobs.rounds(job_id, since_round=since_round)
    # A poll for the new rounds reads round 0 (the gain's reference) and nothing else again.
    round0 = None if since_round == 0 else next(iter(jobs.rounds(job_id, until_round=0)), None)
    last = None if rounds or job.last_round is None else jobs.last_round(job_id)
    return HistoryPublic.from_records(job, rounds, since_round, round0=round0, last=last)


@router.post("/{job_id}/cancel", response_model=JobPublic,
             responses={**_ERRORS, **documented({409: "the job is already finished"})})
def cancel_job(job: ChangeableJob, jobs: JobStoreDep) -> JobPublic:
    """Cancel an unfinished job. It keeps its committed rounds (and its model, if any)."""
    job_id = job.id
    if job.terminal:
        raise HTTPException(status.HTTP_409_CONFLICT,
                            f"job {job_id} is already {job.status.value}; only unfinished jobs can be cancelled")
    return JobPublic.from_record(jobs.set_status(job_id, JobStatus.CANCELLED))  # a lost race is 409 too


@router.get("/{job_id}/export", response_class=Response, responses={
    **_ERRORS, **DAMAGED, **documented({422: "a material the model does not hold, too many, or two whose names "
                                              "become one file name",
                                        501: "this service lacks the format's runtime (the neuenh[export] extra)"}),
    **file_response("a zip of the exported files (neuenh export --format FORMAT): GLSL, ONNX or the Mitsuba "
                    "plugin's")})
def export_model(job: VisibleJob, jobs: JobStoreDep, artifacts: ArtifactStoreDep,
                 format: Annotated[Literal["glsl", "onnx", "mitsuba"], Query(description="what to write")],
                 material: Annotated[list[str] | None, Query(max_length=MAX_EXPORTED,
                                                             description="repeat for several; default all")] = None
                 ) -> Response:
    """The last committed model's materials in a renderer's own format, as a zip archive (the files
    ``neuenh export MODEL --format FORMAT`` writes; docs/EXPORT.md)."""
    from neuenh.export import ExportError, MissingRuntime, export

    bundle = Bundle.from_bytes(artifacts.get(_last_round(job, jobs).artifact_key))
    names = list(bundle.materials.names) if bundle.materials is not None else []
    wanted = material or names
    missing = [m for m in wanted if m not in names]
    if missing or not wanted:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"job {job.id}'s model holds no material {', '.join(map(repr, missing[:5]))}"
                            if missing else f"job {job.id}'s model holds no materials")
    if len(wanted) > MAX_EXPORTED:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"{len(wanted)} materials; export at most {MAX_EXPORTED} at a time (?material=NAME)")
    params = {m: bundle.materials.as_params(names.index(m)) for m in wanted}
    buffer = io.BytesIO()
    with tempfile.TemporaryDirectory(prefix="neuenh-export-") as tmp:
        out = Path(tmp) / "export"
        try:
            export(bundle.model, params, format, out)
        except MissingRuntime as exc:
            raise HTTPException(status.HTTP_501_NOT_IMPLEMENTED, str(exc)) from None
        except ExportError as exc:  # e.g. two material names that clean up to one file name
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, f"material: {exc}") from None
        with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
            for path in sorted(out.rglob("*")):
                if path.is_file():
                    archive.write(path, path.relative_to(out))
    filename = f"neuenh-{job.id}-{format}.zip"
    return Response(buffer.getvalue(), media_type="application/zip",
                    headers={"Content-Disposition": f'attachment; filename="{filename}"'})


def _last_round(job, jobs) -> RoundRecord:
    """The job's last committed round (404 before round 0 commits)."""
    last = jobs.last_round(job.id)
    if last is None or last.artifact_key is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            f"job {job.id} has no committed round yet (status {job.status.value}); "
                            f"its model is available once round 0 is committed")
    return last


@router.get("/{job_id}/model", response_class=Response, responses={
    **_ERRORS, **DAMAGED,
    **file_response("a zip of the bundle: model.json, weights.safetensors, materials.safetensors")})
def download_model(job: VisibleJob, jobs: JobStoreDep, artifacts: ArtifactStoreDep) -> Response:
    """The last committed bundle as a zip archive (load it with ``Bundle.load`` once extracted)."""
    job_id = job.id
    last = _last_round(job, jobs)
    bundle = Bundle.from_bytes(artifacts.get(last.artifact_key))
    bundle.provenance.update({"job": job_id, "round": last.index, "status": job.status.value})
    buffer = io.BytesIO()
    with tempfile.TemporaryDirectory(prefix="neuenh-model-") as tmp:
        directory = bundle.save(Path(tmp) / "model")
        with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
            for path in sorted(directory.iterdir()):
                archive.write(path, path.name)
    filename = f"neuenh-{job_id}-round{last.index:04d}.zip"
    return Response(buffer.getvalue(), media_type="application/zip",
                    headers={"Content-Disposition": f'attachment; filename="{filename}"',
                             "X-Neuenh-Round": str(last.index), "X-Neuenh-State": last.winner_state})
