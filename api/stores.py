"""The artifact store a service's settings name and the lock on its job store, built where the
service starts (the app's lifespan, ``neuenh serve``, a plan's worker process): their own module so
that each of them imports them without importing the others — ``neuenh serve`` checks both before it
imports the app (and torch).
"""

from __future__ import annotations

from neuenh_service.storage import ArtifactStore, LocalArtifactStore, OwnerLock

from .settings import Settings

__all__ = ["artifact_store", "owner_lock"]


def artifact_store(settings: Settings) -> ArtifactStore:
    """The bucket when ``s3_bucket`` is set (checked: a ``StorageError`` naming a missing bucket or
    an unreachable endpoint), else the directory ``data_dir/artifacts``."""
    if not settings.s3_bucket:
        return LocalArtifactStore(settings.data_dir / "artifacts")
    from neuenh_service.storage.s3 import S3ArtifactStore  # boto3 only for a bucket

    secret = settings.s3_secret_access_key
    return S3ArtifactStore(settings.s3_bucket, prefix=settings.s3_prefix,
                           endpoint_url=settings.s3_endpoint_url, region=settings.s3_region,
                           access_key_id=settings.s3_access_key_id,
                           secret_access_key=secret.get_secret_value() if secret else None,
                           max_attempts=settings.s3_max_attempts)


def owner_lock(settings: Settings) -> OwnerLock:
    """The lock that lets one process run the jobs of ``data_dir``'s store at a time."""
    return OwnerLock(settings.data_dir / "owner.lock", owner="neuenh serve")
