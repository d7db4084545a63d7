"""``neuenh-client export JOB --format glsl|onnx|mitsuba [-o DIR] [--material NAME ...]``: a job's
model and materials in a renderer's format, exported by the service and extracted here (an archive
naming a path outside DIR is refused)."""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

from .api import DOWNLOAD_TIMEOUT_S, Api, ClientError
from .commands import Commands, job_arg


def add_parser(commands: Commands) -> None:
    p = commands.add("export", run, "a job's model and materials in a renderer's format (GLSL, ONNX, Mitsuba 3)")
    job_arg(p)
    p.add_argument("--format", required=True, choices=("glsl", "onnx", "mitsuba"), help="what to write")
    p.add_argument("-o", "--output", type=Path, metavar="DIR", help="where to extract the files (default ./neuenh-JOB-FORMAT)")
    p.add_argument("--material", action="append", metavar="NAME", help="only this material (repeat); default all")
    p.add_argument("--force", action="store_true", help="write into an existing non-empty directory")


def run(args, api: Api) -> int:
    target = args.output or Path(f"neuenh-{args.job}-{args.format}")
    if target.exists() and (not target.is_dir() or (any(target.iterdir()) and not args.force)):
        raise ValueError(f"{target} exists and is not empty; choose another -o or pass --force")
    data = api.export(args.job, args.format, args.material, read_timeout=args.timeout or DOWNLOAD_TIMEOUT_S)
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        names = archive.namelist()
        if any(n.startswith("/") or ".." in Path(n).parts for n in names):
            raise ClientError(f"the service sent an archive with unsafe paths: {names[:3]}", 1)
        archive.extractall(target)
    for name in names:
        print(target / name)
    return 0
