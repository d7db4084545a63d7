"""``neuenh-client jobs [--status S ...] [--limit N]`` (also ``list``): jobs, newest first."""

from __future__ import annotations

from ..tables import table
from .api import Api
from .commands import Commands, job_status, json_arg, local_time, note, print_json, rounds_committed


def add_parser(commands: Commands) -> None:
    p = commands.add("jobs", run, "list jobs, newest first", aliases=("list",))
    p.add_argument("--status", action="append", type=str.upper, metavar="STATUS",
                   help="only jobs in this status (repeatable): QUEUED, PREPARING, RUNNING, CONVERGED, ...")
    p.add_argument("--limit", type=int, default=20, help="at most this many (default 20)")
    json_arg(p)


def run(args, api: Api) -> int:
    found = api.jobs(args.status, limit=max(args.limit, 1))
    if args.json:
        print_json(found)
    elif found:
        print(jobs_table(found))
    else:
        note("no jobs" + (f" in status {', '.join(args.status)}" if args.status else ""))
    return 0


def jobs_table(found: list[dict]) -> str:
    """One row per job: id, status, committed rounds, state, model, name, when it was created."""
    rows = [("id", "status", "rounds", "state", "model", "name", "created")]
    for j in found:
        rows.append((j["id"], job_status(j), str(rounds_committed(j)), j["current_state"] or "-", j["model"],
                     j["name"] or "-", local_time(j["created_at"])))
    return table(rows, right=(2,))
