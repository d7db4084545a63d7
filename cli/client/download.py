"""``neuenh-client download JOB [-o DIR|FILE.zip] [--force]``: a job's model (its last committed
round), saved as a bundle directory (``model.json``, ``weights.safetensors``,
``materials.safetensors``) or, for a target ending in ``.zip``, the archive itself. Either way it
is written atomically: extracted beside the target, loaded with ``Bundle.load`` to prove it is
whole, then renamed into place. An existing non-empty target is refused (exit 2) unless ``force``;
the check runs before the download too, so nothing is fetched for nothing.
"""

from __future__ import annotations

import io
import os
import shutil
import tempfile
import zipfile
from pathlib import Path

from neuenh.files import atomic_write

from .api import DOWNLOAD_TIMEOUT_S, JOB_FAILED, USAGE, Api, ClientError
from .commands import Commands, job_arg, json_arg, note, print_json


def add_parser(commands: Commands) -> None:
    p = commands.add("download", run, "download a job's model (its last committed round)")
    job_arg(p)
    p.add_argument("-o", "--output", type=Path, metavar="DIR|FILE.zip",
                   help="a directory to extract the bundle into (default ./neuenh-JOB), or a .zip to keep the archive")
    p.add_argument("--force", action="store_true", help="replace an existing non-empty directory or zip")
    json_arg(p, "print what was saved as JSON")


def run(args, api: Api) -> int:
    target = args.output or default_target(args.job)
    check_target(target, args.force)
    r = api.model(args.job, read_timeout=args.timeout or DOWNLOAD_TIMEOUT_S)
    bundle = save_model(r.content, target, args.force)
    saved = {"job_id": args.job, "round": int(r.headers.get("X-Neuenh-Round", -1)),
             "state": bundle.model.state, "path": str(target)}
    if args.json:
        print_json(saved)
    else:
        print(target)
        note(f"job {args.job} round {saved['round']} (state {saved['state']}) saved to {target}")
    return 0


def default_target(job_id: str) -> Path:
    return Path(f"neuenh-{job_id}")


def is_zip(target: Path) -> bool:
    return target.suffix.lower() == ".zip"


def check_target(target: Path, force: bool) -> None:
    """Refuse a target that cannot be written, or would be overwritten without ``force``."""
    if is_zip(target):
        if target.is_dir():
            raise ClientError(f"{target} is a directory; name a .zip file or a directory to extract into", USAGE)
        if target.exists() and not force:
            raise ClientError(f"{target} exists; use --force to replace it", USAGE)
    elif target.exists():
        if not target.is_dir():
            raise ClientError(f"{target} exists and is not a directory", USAGE)
        if any(target.iterdir()) and not force:
            raise ClientError(f"{target} exists and is not empty; use --force to replace it", USAGE)
    if not target.absolute().parent.is_dir():
        raise ClientError(f"{target.parent}: no such directory", USAGE)


def save_model(archive: bytes, target: Path, force: bool):
    """Write the downloaded ``archive`` to ``target`` (a directory, or a .zip); return the loaded Bundle."""
    from neuenh.checkpoint import Bundle  # (imports torch: only when a model is really saved)

    check_target(target, force)
    parent = target.absolute().parent
    staging = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".tmp", dir=parent))
    try:
        _extract(archive, staging)
        try:
            bundle = Bundle.load(staging)
        except Exception as exc:  # noqa: BLE001 - whatever is wrong with it, it is not a model
            raise ClientError(f"the downloaded model does not load ({exc})", JOB_FAILED) from None
        if is_zip(target):
            atomic_write(target, archive)
        else:
            umask = os.umask(0)
            os.umask(umask)
            staging.chmod(0o777 & ~umask)  # mkdtemp's 0700 is for staging, not for the result
            _move_into_place(staging, target)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return bundle


def _extract(archive: bytes, into: Path) -> None:
    """The archive's files into ``into``; only plain file names are accepted (no folders, no ``..``)."""
    try:
        with zipfile.ZipFile(io.BytesIO(archive)) as z:
            for info in z.infolist():
                name = info.filename
                if info.is_dir() or not name or "/" in name or "\\" in name or name.startswith("."):
                    raise ClientError(f"the downloaded model holds an unexpected entry {name!r}", JOB_FAILED)
                (into / name).write_bytes(z.read(info))
    except zipfile.BadZipFile as exc:
        raise ClientError(f"the service sent a model that is not a zip archive ({exc})", JOB_FAILED) from None


def _move_into_place(staging: Path, target: Path) -> None:
    """Rename ``staging`` to ``target``; an existing target (empty, or replaced under --force) is
    moved aside first and removed only once the new one is in place."""
    old = None
    if target.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".old", dir=target.absolute().parent))
        os.replace(target, old / "previous")
    try:
        os.replace(staging, target)
    except OSError:
        if old is not None:
            os.replace(old / "previous", target)
        raise
    finally:
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
