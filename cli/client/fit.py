"""``neuenh-client fit JOB MEASUREMENTS ...``: fit measured materials with a job's model on the
service (module weights frozen); the tables are checked here first, so a bad one is a usage error
before anything is uploaded. Prints the same report as ``neuenh fit``."""

from __future__ import annotations

from pathlib import Path

from ..tables import fit_report
from .api import FIT_TIMEOUT_S, Api
from .commands import Commands, job_arg, json_arg, print_json


def add_parser(commands: Commands) -> None:
    p = commands.add("fit", run, "fit measured materials with a job's model on the service (module weights frozen)")
    job_arg(p)
    p.add_argument("tables", nargs="+", type=Path, metavar="MEASUREMENTS",
                   help="one table per material (.npz with wi, wo, f_r, or CSV wi_x..wo_z,r,g,b)")
    p.add_argument("--method", choices=("fast", "paper"), default="fast",
                   help="fast (default): Adam with cosine decay; paper: RMSProp lr 1e-3, 1000 epochs")
    p.add_argument("--epochs", type=int, help="override the method's epoch count")
    json_arg(p)


def run(args, api: Api) -> int:
    from neuenh.data.table import load_table

    for table in args.tables:  # a bad table is a usage error before anything is uploaded
        load_table(table)
    data = {"method": args.method, **({"epochs": str(args.epochs)} if args.epochs is not None else {})}
    handles = [open(t, "rb") for t in args.tables]
    try:
        files = [("files", (t.name, h, "application/octet-stream")) for t, h in zip(args.tables, handles)]
        report = api.fit(args.job, files, data, read_timeout=args.timeout or FIT_TIMEOUT_S)
    finally:
        for h in handles:
            h.close()
    if args.json:
        print_json(report)
    else:
        print(f"job {report['job_id']} round {report['round']}: {fit_report(report)}")
    return 0
