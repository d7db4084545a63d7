"""``neuenh-client fit JOB MEASUREMENTS ...``: fit measured materials with a job's model on the
service (module weights frozen); the tables are checked here first, so a bad one is a usage error
before anything is uploaded, and a measured file (RGL, MERL) is drawn here (``cli.draws``, as
``neuenh fit`` draws it) and uploaded as the table of its pairs. Prints the same report as
``neuenh fit``."""

from __future__ import annotations

import io
from pathlib import Path

from neuenh.capacities import CAPACITY_HELP, USER_CAPACITY
from neuenh.data.table import TableError, check_table, looks_like_table

from ..draws import add_draw_arguments, check_draw_arguments, draw, is_measured
from ..tables import fit_report
from .api import FIT_TIMEOUT_S, Api
from .commands import Commands, job_arg, json_arg, print_json


def add_parser(commands: Commands) -> None:
    p = commands.add("fit", run, "fit measured materials with a job's model on the service (module weights frozen)")
    job_arg(p)
    p.add_argument("tables", nargs="+", type=Path, metavar="MEASUREMENTS",
                   help="one table per material (.npz with wi, wo, f_r, or CSV wi_x..wo_z,r,g,b), or a measured "
                        "file (RGL .bsdf, MERL .binary) drawn here")
    p.add_argument("--method", choices=("fast", "paper"), default="fast",
                   help="fast (default): the capacity's fit; paper: RMSProp lr 1e-3, 1000 epochs")
    p.add_argument("--capacity", default=USER_CAPACITY, help=CAPACITY_HELP)
    p.add_argument("--epochs", type=int, help="Adam or RMSProp epochs (default: the protocol's own)")
    p.add_argument("--lbfgs-iterations", type=int, help="a plain model's L-BFGS iterations per phase")
    add_draw_arguments(p)
    json_arg(p)


def run(args, api: Api) -> int:
    check_draw_arguments(args)
    uploads = [_upload(t, args) for t in args.tables]  # every mistake is a usage error before anything is sent
    data = {"method": args.method, "capacity": args.capacity,
            **{k: str(v) for k, v in (("epochs", args.epochs), ("lbfgs_iterations", args.lbfgs_iterations))
               if v is not None}}
    handles = [open(u, "rb") if isinstance(u, Path) else u for _, u in uploads]
    try:
        files = [("files", (name, h, "application/octet-stream")) for (name, _), h in zip(uploads, handles)]
        report = api.fit(args.job, files, data, read_timeout=args.timeout or FIT_TIMEOUT_S)
    finally:
        for h in handles:
            h.close()
    if args.json:
        print_json(report)
    else:
        print(f"job {report['job_id']} round {report['round']}: {fit_report(report)}")
    return 0


def _upload(path: Path, args) -> tuple[str, Path | io.BytesIO]:
    """What goes up for one measurement: a table as it is (checked with numpy alone: no torch), or
    the table of the pairs drawn from a measured file, named after it."""
    try:
        check_table(path)
        return path.name, path
    except TableError:
        if not path.is_file() or looks_like_table(path) or not is_measured(path):  # a bad table: its own error
            raise
    import numpy as np

    fit, _ = draw(path, args)
    table = io.BytesIO()
    np.savez(table, wi=fit.wi.numpy(), wo=fit.wo.numpy(), f_r=fit.f_r.numpy())
    table.seek(0)
    return f"{path.stem}.npz", table
