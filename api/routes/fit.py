"""``POST /v1/jobs/{id}/fit``: fit uploaded measurements with a job's model (its module weights
frozen) and return the fitted per-material parameters and losses.

Each uploaded file is one material, named by its file name: a table (``.npz`` with ``wi``, ``wo``,
``f_r`` or CSV ``wi_x..wo_z,r,g,b[,weight]``; ``neuenh.data.table``), or an RGL ``.bsdf`` or MERL
``.binary`` file (told by content), from which ``samples`` pairs are drawn, ``near_mirror`` of them
near the mirror direction, seeded by ``seed`` — the draw ``neuenh fit`` and ``neuenh-client fit`` make
(``neuenh.study.heldout.draw_measured``), so the three fit the same pairs. The model is the
job's last committed bundle, so a running job can be tried before it ends. Fits run one at a time
(they share the service's CPUs with the candidates being trained): a request that finds another one
running gets 429 with ``Retry-After`` instead of holding a worker thread while it waits. One fit's
work — measurements x epochs, ``FitProtocol.work`` — is bounded by ``NEUENH_MAX_FIT_WORK``.
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Annotated, Literal

from fastapi import APIRouter, File, Form, HTTPException, Request, UploadFile, status

from neuenh.capacities import CAPACITY_HELP, USER_CAPACITY
from neuenh.checkpoint import Bundle
from neuenh.data.draws import DRAW_NEAR_MIRROR, DRAW_SAMPLES
from neuenh.data.samples import Samples
from neuenh.data.table import read_table
from neuenh.fit import FitOptions, fit_materials
from neuenh.study.heldout import draw_measured

from ..deps import ArtifactStoreDep, Authorized, ChangeableJob, FitLockDep, JobStoreDep, SettingsDep, fit_slot
from ..errors import COMMON, DAMAGED, documented
from ..schemas import DrawPublic, FitPublic
from ..uploads import UPLOADABLE, receive, uploaded_kind

router = APIRouter(prefix="/jobs", tags=["jobs"], dependencies=[Authorized], responses=COMMON)

@router.post("/{job_id}/fit", response_model=FitPublic, responses=documented({
    400: "a body that is not multipart/form-data",
    404: "no such job, or no committed round yet",
    413: "upload over NEUENH_MAX_UPLOAD_BYTES",
    422: "an upload that cannot be read, or a request over the service's limits",
    429: "another fit or upload is running: retry after Retry-After seconds"}) | DAMAGED)
def fit_job(
    request: Request, job: ChangeableJob, jobs: JobStoreDep, artifacts: ArtifactStoreDep, settings: SettingsDep, fit_lock: FitLockDep,
    files: Annotated[list[UploadFile], File(description=f"one file per material: {UPLOADABLE}")],
    method: Annotated[Literal["fast", "paper"], Form()] = "fast",
    capacity: Annotated[str, Form(description=CAPACITY_HELP)] = USER_CAPACITY,
    epochs: Annotated[int, Form(ge=0, description="Adam or RMSProp epochs (a plain model's fast fit: L-BFGS "
                                                  "iterations per phase); 0: the protocol's own (latent 300, "
                                                  "paper 1000, plain 300)")] = 0,
    lbfgs_iterations: Annotated[int, Form(ge=0, description="a plain model's L-BFGS iterations per phase; 0: its "
                                                            "own (300)")] = 0,
    samples: Annotated[int, Form(ge=1, description=f"pairs drawn from each RGL or MERL upload (default {DRAW_SAMPLES}); "
                                                   "a table has its rows")] = DRAW_SAMPLES,
    near_mirror: Annotated[float, Form(ge=0.0, le=1.0, description="the share of those pairs with the half vector "
                                                                   f"near the normal (default {DRAW_NEAR_MIRROR})")] = DRAW_NEAR_MIRROR,
    seed: Annotated[int, Form(ge=0, lt=2**32, description="the draws' seed")] = 0,
) -> FitPublic:
    job_id = job.id
    last = jobs.last_round(job_id)
    if last is None or last.artifact_key is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"job {job_id} has no committed round yet "
                                                       f"(status {job.status.value}); nothing to fit with")
    for name, value in (("epochs", epochs), ("lbfgs_iterations", lbfgs_iterations)):
        if value > settings.max_epochs:
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, f"{name}: {value} exceeds this service's "
                                                                       f"limit of {settings.max_epochs} (NEUENH_MAX_EPOCHS)")
    if len(files) > settings.max_materials:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"files: {len(files)} materials exceed this service's limit of {settings.max_materials} "
                            "(NEUENH_MAX_MATERIALS)")
    try:
        options = FitOptions(method=method, capacity=capacity, epochs=epochs or None,
                             lbfgs_iterations=lbfgs_iterations or None)
    except ValueError as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc)) from None
    bundle = Bundle.from_bytes(artifacts.get(last.artifact_key))
    model = bundle.model
    with fit_slot(fit_lock):  # reading uploads costs memory like a fit: one at a time too (else 429)
        measurements, drawn = _read_uploads(files, settings.max_samples, samples, near_mirror, seed)
        protocol = options.protocol_for(model)
        work = protocol.work(measurements)
        if work > settings.max_fit_work:
            # The adaptive fit's validation reads the rows once more: the latent capacity alone may fit.
            latent = options.replace(capacity="latent").protocol_for(model).work(measurements) \
                if protocol.name == "adaptive" else None
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                                f"files: the {protocol.name} fit of {len(measurements):,} measurements at "
                                f"{protocol.budget_epochs} epochs is {work:,} measurement-epochs, over this service's "
                                f"limit of {settings.max_fit_work:,} per fit (NEUENH_MAX_FIT_WORK); send fewer rows, "
                                "ask fewer epochs" + (f" or capacity latent ({latent:,}: no validation)"
                                                      if latent is not None and latent <= settings.max_fit_work else ""))
        result = fit_materials(model, measurements, protocol, trained=bundle.materials, encoder=bundle.encoder)
    request.app.state.metrics.fits.inc()
    draw = DrawPublic(samples=samples, near_mirror=near_mirror, seed=seed, materials=drawn) if drawn else None
    return FitPublic(job_id=job_id, round=last.index, drawn=draw, **result.report(model, measurements))


def _read_uploads(files: list[UploadFile], max_samples: int, samples: int, near_mirror: float, seed: int
                  ) -> tuple[Samples, list[str]]:
    """Every upload's measurements — a table's rows, or ``samples`` pairs drawn from an RGL or MERL
    file as ``neuenh fit`` draws them (``draw_measured``) — and the names of those drawn."""

    def read(path: Path, name: str) -> tuple[Samples, bool]:
        if uploaded_kind(path) == "table":
            return read_table(path, name=name, max_rows=max_samples), False
        if samples > max_samples:  # checked before the file is read (a table's rows are its own)
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, f"samples: {samples} pairs per material exceed "
                                                                       f"this service's limit of {max_samples} (NEUENH_MAX_SAMPLES)")
        return draw_measured(path, samples, near_mirror, seed, name=name)[0], True

    with tempfile.TemporaryDirectory(prefix="neuenh-fit-") as tmp:
        received = receive(files, Path(tmp), read, max_samples)
    return Samples.concat([r.value[0] for r in received]), [r.name for r in received if r.value[1]]
