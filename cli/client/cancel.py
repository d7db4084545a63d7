"""``neuenh-client cancel JOB``: cancel an unfinished job; it keeps its committed rounds.
``neuenh-client cancel --plan PLAN``: cancel an unfinished scene plan; a running one stops at once
and keeps the materials it planned."""

from __future__ import annotations

from .api import Api
from .commands import Commands, json_arg, print_json, rounds_committed


def add_parser(commands: Commands) -> None:
    p = commands.add("cancel", run, "cancel an unfinished job (it keeps its committed rounds) or, with --plan, "
                                     "a scene plan")
    p.add_argument("job", metavar="ID", help="the job id (with --plan: the plan id)")
    p.add_argument("--plan", action="store_true", help="ID is a scene plan's (neuenh-client plan), not a job's")
    json_arg(p)


def run(args, api: Api) -> int:
    if args.plan:
        plan = api.cancel_plan(args.job)
        line = (f"plan {plan['id']}: {plan['status']} (it keeps its {plan['materials_done']} planned "
                f"material(s) of {plan['materials_total'] or '?'})")
    else:
        job = plan = api.cancel(args.job)
        line = f"job {job['id']}: {job['status']} (it keeps its {rounds_committed(job)} committed round(s))"
    if args.json:
        print_json(plan)
    else:
        print(line)
    return 0
