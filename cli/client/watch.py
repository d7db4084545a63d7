"""``neuenh-client watch JOB``: follow a job until it ends (Ctrl-C stops watching, not the job)."""

from __future__ import annotations

from .api import Api
from .commands import Commands, job_arg, json_arg
from .follow import follow_args, follow_to_end


def add_parser(commands: Commands) -> None:
    p = commands.add("watch", run, "follow a job until it ends (Ctrl-C stops watching, not the job)")
    job_arg(p)
    json_arg(p, "print the finished job as JSON")
    follow_args(p)


def run(args, api: Api) -> int:
    return follow_to_end(api, args.job, args)
