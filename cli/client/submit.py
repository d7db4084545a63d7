"""``neuenh-client submit [SPEC] [flags] [--wait]``: submit a search job. The spec is a file's (or
the quickstart's) with the flags applied, validated here so a bad one is a usage error before the
service is contacted. Prints the job id (``--json``: the job); ``--wait`` follows it to the end."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from .api import Api
from .commands import Commands, json_arg, note, print_json
from .follow import follow_args, follow_to_end

# ``submit`` without a SPEC: the quickstart's search on a small synthetic zoo (examples/quickstart.yaml).
QUICKSTART = {
    "model": "ggx",
    "search": {"radius": 1, "epochs_per_round": 10, "max_rounds": 8},
    "train": {"lr": 5.0e-3, "batch_size": 4096},
    "data": [{"source": "synthetic_zoo", "materials": 16, "samples": 2000, "seed": 1}],
}
# flag -> where it goes in the spec
OVERRIDES = {"name": ("name",), "model": ("model",), "epochs": ("search", "epochs_per_round"),
             "max_rounds": ("search", "max_rounds"), "radius": ("search", "radius"), "priority": ("priority",)}
DURATION_UNITS = {"s": 1.0, "m": 60.0, "h": 3600.0, "d": 86400.0}


def add_parser(commands: Commands) -> None:
    p = commands.add("submit", run, "submit a search job (a spec file, flags, or both)")
    p.add_argument("spec", type=Path, nargs="?", metavar="SPEC",
                   help="a job spec (YAML or JSON); without it, the quickstart's search on a small synthetic zoo")
    p.add_argument("--name", help="the job's name")
    p.add_argument("--model", help="the analytical model to enhance (default ggx)")
    p.add_argument("--epochs", type=int, help="search.epochs_per_round")
    p.add_argument("--max-rounds", type=int, help="search.max_rounds")
    p.add_argument("--radius", type=int, help="search.radius (candidates differ in up to this many positions)")
    p.add_argument("--priority", type=int, help="queued jobs start highest priority first (default 0)")
    p.add_argument("--budget", type=budget, metavar="wall=DURATION,cpu=DURATION",
                   help="stop the job at its last committed round once it has run this long (wall) or its "
                        "candidates have held this much CPU time (cpu); e.g. wall=2h,cpu=20h or 90m (wall)")
    p.add_argument("--idempotency-key", metavar="KEY", help="submitting again with the same key returns the same job")
    p.add_argument("--wait", action="store_true",
                   help="follow the job until it ends; exit 0 if it converged or stopped, 1 if it failed or was cancelled")
    json_arg(p, "print the job as JSON (with --wait, the finished job) instead of its id")
    follow_args(p)


def run(args, api: Api) -> int:
    job, created = api.submit(job_spec(args), args.idempotency_key)
    if not args.json:
        print(job["id"], flush=True)
    note(f"job {job['id']} {'submitted' if created else 'already submitted with this key'} "
         f"({job['status'].lower()})")
    if not args.wait:
        if args.json:
            print_json(job)
        else:
            note(f"follow it with: neuenh-client watch {job['id']}")
        return 0
    return follow_to_end(api, job["id"], args)


def job_spec(args) -> dict:
    """The spec to send: the file's (or the quickstart's) with the flags applied, validated."""
    from neuenh_service.orchestrator.spec import load_spec, parse_spec

    data = load_spec(args.spec).model_dump(mode="json") if args.spec else json.loads(json.dumps(QUICKSTART))
    for flag, path in OVERRIDES.items():
        value = getattr(args, flag)
        if value is not None:
            node = data
            for key in path[:-1]:
                node = node.setdefault(key, {})
            node[path[-1]] = value
    if args.budget:
        data.setdefault("budget", {}).update(args.budget)
    return parse_spec(data).model_dump(mode="json")


def duration(text: str) -> float:
    """Seconds from "90", "90s", "15m", "2h" or "1d"."""
    number, unit = (text[:-1], text[-1]) if text and text[-1] in DURATION_UNITS else (text, "s")
    try:
        seconds = float(number) * DURATION_UNITS[unit]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a duration (e.g. 90, 90s, 15m, 2h, 1d)") from None
    if not 0 < seconds < float("inf"):
        raise argparse.ArgumentTypeError(f"{text!r}: a budget must be a positive duration")
    return seconds


def budget(text: str) -> dict[str, float]:
    """``--budget``: "wall=2h,cpu=20h" (either or both), or one duration meaning the wall time."""
    keys = {"wall": "wall_s", "wall_s": "wall_s", "cpu": "cpu_s", "cpu_s": "cpu_s"}
    out: dict[str, float] = {}
    for part in text.split(","):
        key, sep, value = part.partition("=")
        if not sep:
            key, value = "wall", key
        if key.strip() not in keys:
            raise argparse.ArgumentTypeError(f"unknown budget {key.strip()!r}; use wall=DURATION and/or cpu=DURATION")
        out[keys[key.strip()]] = duration(value.strip())
    return out
