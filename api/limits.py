"""What one submitted job or scene plan may ask of this service (``Settings.max_*``). A spec over a
limit is refused with 422 and a detail naming the field, its value and the setting that bounds it."""

from __future__ import annotations

from math import comb
from pathlib import Path
from typing import Any

from fastapi import HTTPException, status

from neuenh.files import existing
from neuenh.scene import SceneSpec
from neuenh_service.orchestrator.executor import ClusterInfo, Resources
from neuenh_service.orchestrator.spec import JobSpec

from .settings import Settings


def candidates_bound(spec: JobSpec) -> int:
    """Most candidates a round can have: the Hamming ball of ``search.radius`` over the positions
    that are not fixed, each changed position taking any of the other ``m - 1`` digits."""
    free = len(spec.positions()) - len(spec.search.fixed)
    m = spec.digits()
    return sum(comb(free, d) * (m - 1) ** d for d in range(min(spec.search.radius, free) + 1))


def outside_data_roots(spec: JobSpec, settings: Settings) -> list[str]:
    """Files a spec's sources would read that the service must not read (``path_problem``), so a
    caller cannot make the service read any file."""
    return [problem for i, source in enumerate(spec.data) for path in source_paths(source)
            if (problem := path_problem(f"data.{i}", path, settings)) is not None]


def path_problem(where: str, path: str, settings: Settings) -> str | None:
    """Why a request must not name ``path`` (at ``where``), or None: it lies outside the configured
    data roots (after resolving ``..`` and symbolic links), or it is a name no file system holds or
    the service cannot read (a NUL byte, a name too long, a loop of links, a file where a folder
    should be, no permission) — found at submission, not as a traceback of the job or plan that reads
    it. A file that does not exist yet is not refused here: reading it names it."""
    roots = [root.resolve() for root in settings.data_roots]
    try:
        resolved = Path(path).resolve()
    except (ValueError, OSError, RuntimeError) as exc:  # RuntimeError: Python 3.11's "Symlink loop"
        return f"{where}: {path!r} is not a usable path ({getattr(exc, 'strerror', None) or exc})"
    if not any(resolved.is_relative_to(root) for root in roots):
        allowed = ", ".join(map(str, roots)) or "none configured"
        return f"{where}: {path} is outside the data roots ({allowed}; NEUENH_DATA_ROOTS)"
    try:  # only inside the roots: what stat says of other files is none of the caller's business
        resolved.stat()
    except FileNotFoundError:
        return None
    except OSError as exc:
        return f"{where}: {path!r} is not a usable path ({exc.strerror or exc})"
    return None


def source_paths(source) -> list[str]:
    return getattr(source, "paths", None) or ([source.path] if hasattr(source, "path") else [])


def known_materials(source) -> int | None:
    """How many materials a source yields, when the spec alone says so."""
    materials = getattr(source, "materials", None)
    if isinstance(materials, int):
        return materials
    if isinstance(materials, list):
        return len(materials)
    return len(source.paths) if hasattr(source, "paths") else None


# Bytes per measurement while a dataset is prepared and trained on: wi, wo, f_r (float32) and the
# material index (int64) = 44 B, held about four times over (generated, split, shared with the
# workers, a training batch's intermediates).
BYTES_PER_SAMPLE = 4 * 44
# Bytes per material beyond its samples: the source object, its parameters and the per-material
# tables (measured: a synthetic material costs ~20 KB while preparing; 2.5x headroom).
BYTES_PER_MATERIAL = 50_000


def estimated_bytes(spec: JobSpec) -> int:
    """A job's memory while preparing and training, from its spec alone (sources whose size the
    spec does not say count as none: their files are bounded by the data roots)."""
    samples = sum((known_materials(s) or 0) * (getattr(s, "samples", 0) or 0) for s in spec.data)
    materials = sum(known_materials(s) or 0 for s in spec.data)
    return samples * BYTES_PER_SAMPLE + materials * BYTES_PER_MATERIAL


def module_weights(spec: JobSpec, hidden: list[int]) -> int:
    """Weights of the largest module of that hidden shape: the widest input is a term module's
    (all parameters, the latent and both directions), the widest output 3 (RGB)."""
    widths = [spec.model_instance().module_specs.total_width + spec.latent_dim + 6, *hidden, 3]
    return sum(a * b + b for a, b in zip(widths[:-1], widths[1:]))


def epoch_settings(value: Any, where: str = "") -> list[tuple[str, int]]:
    """Every epoch count a spec sets (``search.epochs_per_round``, ``search.warmup_epochs``,
    ``search.polish_epochs``, ... any field whose name has the word ``epochs``), by dotted path: each is
    training the service does, so each counts against ``NEUENH_MAX_EPOCHS``."""
    found = []
    if isinstance(value, dict):
        for key, item in value.items():
            path = f"{where}.{key}" if where else str(key)
            if "epochs" in str(key).split("_") and isinstance(item, int) and not isinstance(item, bool):
                found.append((path, item))
            else:
                found += epoch_settings(item, path)
    elif isinstance(value, list):
        for i, item in enumerate(value):
            found += epoch_settings(item, f"{where}.{i}")
    return found


def epoch_problems(spec_json: Any, settings: Settings) -> list[str]:
    """Each epoch count of ``spec_json`` (a job's or a scene's spec as JSON) over ``NEUENH_MAX_EPOCHS``."""
    return [f"{where}: {epochs} exceeds this service's limit of {settings.max_epochs} (NEUENH_MAX_EPOCHS)"
            for where, epochs in epoch_settings(spec_json) if epochs > settings.max_epochs]


def unsatisfiable(spec: JobSpec, cluster: ClusterInfo) -> list[str]:
    """What a candidate asks that no node of ``cluster`` has: such a job would wait forever
    (RUNNING 0/n, every later job queued behind it). Nothing, while no worker has joined."""
    if not any(n.alive and n.cpus > 0 for n in cluster.nodes):
        return []
    resources = Resources(spec.resources.cpus_per_candidate, spec.resources.gpus_per_candidate)
    return [f"resources.{p}: no candidate could ever start" for p in cluster.missing(resources)]


def check_limits(spec: JobSpec, settings: Settings, cluster: ClusterInfo | None = None) -> None:
    problems = []
    n = candidates_bound(spec)
    if n > settings.max_candidates_per_round:
        problems.append(f"search.radius: {spec.search.radius} gives up to {n} candidates per round; this "
                        f"service allows {settings.max_candidates_per_round} (NEUENH_MAX_CANDIDATES_PER_ROUND)")
    settings_used = spec.model_dump(mode="json")
    if not spec.holds_out():  # no held-out materials: the fit score is never computed
        settings_used["search"].pop("fit_score")
    problems += epoch_problems(settings_used, settings)
    if spec.resources.cpus_per_candidate < settings.min_cpus_per_candidate:
        problems.append(f"resources.cpus_per_candidate: {spec.resources.cpus_per_candidate} is below this "
                        f"service's floor of {settings.min_cpus_per_candidate} (NEUENH_MIN_CPUS_PER_CANDIDATE): "
                        "every candidate is a worker process of its own, so CPUs split finer only add processes")
    if spec.latent_dim > settings.max_latent_dim:
        problems.append(f"latent_dim: {spec.latent_dim} exceeds this service's limit of "
                        f"{settings.max_latent_dim} (NEUENH_MAX_LATENT_DIM)")
    widest = max(max(widths) for widths in (spec.module.hidden, *spec.module.alternatives))
    if widest > settings.max_module_width:
        problems.append(f"module: a hidden width of {widest} exceeds this service's limit of "
                        f"{settings.max_module_width} (NEUENH_MAX_MODULE_WIDTH)")
    for hidden in (spec.module.hidden, *spec.module.alternatives):
        if len(hidden) > settings.max_module_depth:
            problems.append(f"module: {len(hidden)} hidden layers exceed this service's limit of "
                            f"{settings.max_module_depth} (NEUENH_MAX_MODULE_DEPTH)")
        elif (weights := module_weights(spec, hidden)) > settings.max_module_weights:
            problems.append(f"module: hidden {hidden} makes {weights} weights per module; this service allows "
                            f"{settings.max_module_weights} (NEUENH_MAX_MODULE_WEIGHTS)")
    materials = sum(known_materials(s) or 0 for s in spec.data)
    if materials > settings.max_materials:
        problems.append(f"data: {materials} materials exceed this service's limit of {settings.max_materials} "
                        "(NEUENH_MAX_MATERIALS)")
    memory = estimated_bytes(spec)
    if memory > settings.max_job_memory_bytes:
        problems.append(f"data: preparing and training this job needs about {memory / 1e9:.1f} GB; this service "
                        f"allows {settings.max_job_memory_bytes / 1e9:.1f} GB (NEUENH_MAX_JOB_MEMORY_BYTES)")
    total = 0
    for i, source in enumerate(spec.data):
        samples = getattr(source, "samples", None)
        if samples is not None and samples > settings.max_samples:
            problems.append(f"data.{i}.samples: {samples} exceeds this service's limit of "
                            f"{settings.max_samples} per material (NEUENH_MAX_SAMPLES)")
        materials = known_materials(source)
        total += (materials or 0) * (samples or 0)
    if total > settings.max_total_samples:
        problems.append(f"data: {total} measurements in all exceed this service's limit of "
                        f"{settings.max_total_samples} (NEUENH_MAX_TOTAL_SAMPLES)")
    problems += outside_data_roots(spec, settings)
    if cluster is not None and not settings.autoscaling:
        problems += unsatisfiable(spec, cluster)
    if problems:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, "job spec refused: " + "; ".join(problems))


# Bytes a measured file holds once read, per byte of the file (measured: an RGL material holds 2.8x
# its file's size, its warp tables beside its copied fields; tracemalloc over ten loads; headroom).
BYTES_PER_FILE_BYTE = 4


def scene_materials(spec: SceneSpec) -> int:
    """Materials a scene names, as far as the scene alone says (a capture with a region counts its
    texels at its stride; one without counts 1 here, and every texel once read: ``PlanRunner``)."""
    count = 0
    for entry in spec.materials:
        region = getattr(entry, "region", None)
        if region is not None:
            x0, y0, x1, y1 = region
            count += max(0, -(-(x1 - x0) // entry.stride)) * max(0, -(-(y1 - y0) // entry.stride))
        else:
            count += 1
    return count


def scene_file_bytes(spec: SceneSpec, base: Path) -> int:
    """The sizes of the measured files a scene reads (each entry its own: one file named twice is
    read twice); files that do not exist count nothing (the plan fails on them)."""
    paths = [base / entry.path for entry in spec.materials if getattr(entry, "path", None)]
    return sum(status.st_size for status in map(existing, paths) if status is not None)


def plan_problems(spec: SceneSpec, settings: Settings, base: Path) -> list[str]:
    """What in a scene plan exceeds this service's limits, each naming the field and the setting (the
    same settings as jobs: a plan fits and renders like one)."""
    fit, problems = spec.fit, []
    for field in ("samples", "test_samples"):
        value = getattr(fit, field)
        if value > settings.max_samples:
            problems.append(f"fit.{field}: {value} exceeds this service's limit of {settings.max_samples} "
                            "per material (NEUENH_MAX_SAMPLES)")
    problems += epoch_problems(spec.model_dump(mode="json"), settings)
    materials = scene_materials(spec)
    if materials > settings.max_materials:
        problems.append(f"materials: {materials} materials exceed this service's limit of {settings.max_materials} "
                        "(NEUENH_MAX_MATERIALS)")
    measurements = materials * (fit.samples + fit.test_samples)
    if measurements > settings.max_total_samples:
        problems.append(f"materials: {materials} materials x {fit.samples + fit.test_samples} fit and test samples "
                        f"= {measurements} measurements exceed this service's limit of {settings.max_total_samples} "
                        "(NEUENH_MAX_TOTAL_SAMPLES)")
    if spec.render.size > settings.max_render_size:
        problems.append(f"render.size: {spec.render.size} exceeds this service's limit of {settings.max_render_size} "
                        "pixels per side (NEUENH_MAX_RENDER_SIZE)")
    memory = measurements * BYTES_PER_SAMPLE + scene_file_bytes(spec, base) * BYTES_PER_FILE_BYTE
    if memory > settings.max_job_memory_bytes:
        problems.append(f"materials: planning this scene needs about {memory / 1e9:.1f} GB (its files read once per "
                        f"entry); this service allows {settings.max_job_memory_bytes / 1e9:.1f} GB "
                        "(NEUENH_MAX_JOB_MEMORY_BYTES)")
    return problems
