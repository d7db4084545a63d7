"""Service settings, read from the environment (prefix ``NEUENH_``) or passed in by tests.

    NEUENH_DATA_DIR=./neuenh-data NEUENH_API_TOKEN=... NEUENH_RAY_ADDRESS=ray://head:10001 python -m neuenh_service.api

With ``NEUENH_S3_BUCKET`` set, artifacts (checkpoints, cached datasets) live in that bucket of an
S3-compatible store instead of ``data_dir/artifacts``; the job store stays in ``data_dir``.
"""

from __future__ import annotations

import ipaddress
import socket
from pathlib import Path
from typing import Literal

from pydantic import Field, SecretStr
from pydantic_settings import BaseSettings, SettingsConfigDict


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="NEUENH_", extra="ignore")

    @property
    def has_tokens(self) -> bool:
        """Whether callers must present a token (``NEUENH_API_TOKEN`` or ``NEUENH_TOKENS_FILE``)."""
        return self.api_token is not None or self.tokens_file is not None

    data_dir: Path = Field(Path("./neuenh-data"), description="jobs.sqlite and artifacts/ live here")
    host: str = "127.0.0.1"
    port: int = Field(8000, ge=0, le=65535)
    api_token: SecretStr | None = Field(
        None, description="when set, every /v1 route but /health needs 'Authorization: Bearer <token>'")
    tokens_file: Path | None = Field(None, description=(
        "named tokens with roles (admin, submit, read), hashed, as JSON (api/auth.py); re-read on SIGHUP"))
    ray_address: str | None = Field(None, description="join this Ray cluster; embedded Ray when unset")
    access_log: bool = Field(False, description="log every request (uvicorn's access log)")
    log_format: Literal["text", "json"] = Field("text", description=(
        "'json': one JSON object per log line (time, level, logger, message), for log collectors"))
    allowed_hosts: list[str] = Field(default_factory=list, description=(
        "Host header values (names, without the port) requests may carry (JSON list in NEUENH_ALLOWED_HOSTS); "
        "empty: any when a token is set, else loopback names only (a DNS-rebinding page gets 421)"))
    head_timeout: float = Field(10.0, gt=0.0, description="seconds a connection has to send a complete "
                                                          "request head (after opening, and after each "
                                                          "response) before it is closed")
    max_connections: int = Field(512, ge=1, description="open connections beyond which requests get 503")
    ray_num_cpus: int | None = Field(None, ge=1, description="CPUs of the embedded Ray (default: all)")
    data_roots: list[Path] = Field(
        default_factory=list,
        description="folders whose files a job's data sources may read (JSON list in "
                    "NEUENH_DATA_ROOTS); with none, file-based sources are refused")

    # Limits on what one submitted job may ask for (checked on POST /v1/jobs, 422 when exceeded).
    max_candidates_per_round: int = Field(
        64, ge=1, description="upper bound of the Hamming ball size implied by search.radius")
    max_epochs: int = Field(1000, ge=1, description=(
        "largest epoch count of any setting: a job's search.epochs_per_round, warmup_epochs, polish_epochs; "
        "a fit's epochs; a scene plan's fit.epochs"))
    min_cpus_per_candidate: float = Field(0.25, ge=0.0001, description=(
        "smallest resources.cpus_per_candidate: every candidate is a Ray worker process (~300 MB), so finer "
        "splits only multiply processes and memory (Ray itself cannot express less than 0.0001)"))
    max_samples: int = Field(1_000_000, ge=1, description="largest per-material 'samples' of a data source")
    max_total_samples: int = Field(20_000_000, ge=1, description="largest dataset (materials x samples, "
                                                                 "where the spec says both)")
    max_latent_dim: int = Field(256, ge=0, description="largest latent_dim")
    max_module_width: int = Field(1024, ge=1, description="largest hidden width of a neural module")
    max_module_depth: int = Field(16, ge=1, description="most hidden layers of a neural module")
    max_module_weights: int = Field(1_000_000, ge=1, description="most weights of one neural module")
    autoscaling: bool = Field(False, description=(
        "the cluster grows on demand: accept jobs whose candidates no current node can hold"))
    resource_wait_s: float = Field(600.0, ge=0.0, description=(
        "how long a job waits for a node that can hold one of its candidates before it fails"))
    max_running_jobs: int | None = Field(None, ge=1, description=(
        "jobs run at once, sharing the cluster fairly (unset: enough to fill it, at least 2: one per 12 "
        "CPUs, a radius-1 GGX round)"))
    default_budget_wall_s: float | None = Field(None, gt=0.0, description=(
        "budget.wall_s of a job whose spec sets none (stored in the spec at submission)"))
    default_budget_cpu_s: float | None = Field(None, gt=0.0, description=(
        "budget.cpu_s of a job whose spec sets none (stored in the spec at submission)"))
    max_materials: int = Field(10_000, ge=1, description="most materials of a job's dataset")
    max_job_memory_bytes: int = Field(8_000_000_000, ge=1, description=(
        "largest estimated memory of preparing and training a job (api/limits.py, estimated_bytes)"))
    max_request_bytes: int = Field(1_000_000, ge=1, description="largest request body; 413 beyond")
    max_upload_bytes: int = Field(64_000_000, ge=1, description="largest measurement upload to "
                                                                  "POST /v1/jobs/{id}/fit; 413 beyond")

    # Artifacts in an S3-compatible bucket (AWS S3, MinIO, ...) instead of data_dir/artifacts.
    s3_bucket: str | None = Field(None, description="store artifacts in this bucket (it must exist)")
    s3_prefix: str = Field("", description="key prefix inside the bucket, e.g. 'neuenh/prod'")
    s3_endpoint_url: str | None = Field(None, description="e.g. http://minio:9000; AWS when unset")
    s3_region: str | None = Field(None, description="the bucket's region (default us-east-1)")
    s3_access_key_id: str | None = Field(None, description="with the secret; boto3's usual chain "
                                                             "(AWS_* variables, instance role) when unset")
    s3_secret_access_key: SecretStr | None = None
    s3_max_attempts: int = Field(5, ge=1, description="tries per S3 request on transient errors")

    default_gpus_per_candidate: float = Field(
        0.0, ge=0.0, description="resources.gpus_per_candidate of a job whose spec does not set it "
                                 "(a cluster with GPU workers: e.g. 0.25 puts four candidates on a GPU)")

    plan_cpus: int = Field(1, ge=1, description=(
        "CPU threads a scene plan's process uses; a running plan holds as many of the cluster's fair share"))
    max_render_size: int = Field(256, ge=8, description="largest render.size (pixels per side) of a scene plan")
    max_fit_work: int = Field(10_000_000, ge=1, description=(
        "most measurement-epochs one POST /v1/jobs/{id}/fit may ask (FitProtocol.work): the rows the fit reads x "
        "the epochs it reads them (its method's default when unset; a latent fit reads at most 20,000 of each "
        "material's, an adaptive one also chooses on at most 20,000); the default auto fit of 10,000 "
        "measurements is 6,000,000 and took 29 s on 2 cores (docs/RESULTS.md)"))

    shutdown_grace_s: float = Field(
        30.0, ge=0.0, description="how long shutdown waits for the running job to reach a safe stop")


def is_loopback(host: str) -> bool:
    """Whether every address ``host`` resolves to is a loopback address (a name is resolved, not
    matched by prefix: ``localhost.example`` is somebody's machine; an unresolvable name is not)."""
    try:
        infos = socket.getaddrinfo(host, None, proto=socket.IPPROTO_TCP)
    except (socket.gaierror, UnicodeError):
        return False
    return bool(infos) and all(ipaddress.ip_address(info[4][0].split("%")[0]).is_loopback for info in infos)


def check_listen_address(settings: Settings) -> None:
    """Refuse to serve beyond this machine without a token (a ValueError naming the fix)."""
    if not settings.has_tokens and not is_loopback(settings.host):
        raise ValueError(f"refusing to listen on {settings.host} without NEUENH_API_TOKEN: anyone on the "
                         "network could submit jobs; set a token or listen on 127.0.0.1")
