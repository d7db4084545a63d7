"""``neuenh-client cancel JOB``: cancel an unfinished job; it keeps its committed rounds."""

from __future__ import annotations

from .api import Api
from .commands import Commands, job_arg, json_arg, print_json, rounds_committed


def add_parser(commands: Commands) -> None:
    p = commands.add("cancel", run, "cancel an unfinished job (it keeps its committed rounds)")
    job_arg(p)
    json_arg(p)


def run(args, api: Api) -> int:
    job = api.cancel(args.job)
    if args.json:
        print_json(job)
    else:
        print(f"job {job['id']}: {job['status']} (it keeps its {rounds_committed(job)} committed round(s))")
    return 0
