"""``neuenh-client fit JOB MEASUREMENTS ...``: fit measured materials with a job's model on the
service (module weights frozen); the tables are checked here first, so a bad one is a usage error
before anything is uploaded. Prints the same report as ``neuenh fit``."""

from __future__ import annotations

from pathlib import Path

from neuenh.data.table import check_table

from ..tables import fit_report
from .api import FIT_TIMEOUT_S, Api
from .commands import Commands, job_arg, json_arg, print_json


def add_parser(commands: Commands) -> None:
    p = commands.add("fit", run, "fit measured materials with a job's model on the service (module weights frozen)")
    job_arg(p)
    p.add_argument("tables", nargs="+", type=Path, metavar="MEASUREMENTS",
                   help="one table per material (.npz with wi, wo, f_r, or CSV wi_x..wo_z,r,g,b)")
    p.add_argument("--method", choices=("fast", "paper"), default="fast",
                   help="fast (default): the capacity's fit; paper: RMSProp lr 1e-3, 1000 epochs")
    p.add_argument("--capacity", default="latent",
                   help="a model with modules: latent (default), auto (chosen per material by cross-validation), "
                        "original, analytical, last-layer, low-rank or full")
    p.add_argument("--epochs", type=int, help="Adam or RMSProp epochs (default: the protocol's own)")
    p.add_argument("--lbfgs-iterations", type=int, help="a plain model's L-BFGS iterations per phase")
    json_arg(p)


def run(args, api: Api) -> int:
    for table in args.tables:  # a bad table is a usage error before anything is uploaded (numpy only: no torch)
        check_table(table)
    data = {"method": args.method, "capacity": args.capacity,
            **{k: str(v) for k, v in (("epochs", args.epochs), ("lbfgs_iterations", args.lbfgs_iterations))
               if v is not None}}
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
