"""``neuenh-client``: the search service from the command line.

    neuenh-client submit SPEC.yaml [--wait]     # the job id on stdout; --wait follows it to the end
    neuenh-client status [JOB]                  # a job, or the service, its cluster and recent jobs
    neuenh-client jobs [--status RUNNING]       # jobs, newest first (also: list)
    neuenh-client history JOB                   # committed rounds as a table
    neuenh-client watch JOB                     # follow a job until it ends
    neuenh-client cancel JOB
    neuenh-client download JOB [-o DIR|FILE.zip]
    neuenh-client export JOB --format glsl|onnx|mitsuba [-o DIR] [--material NAME ...]
    neuenh-client fit JOB measurements.npz ...  # fit materials with the job's model, on the service
    neuenh-client plan SCENE.yaml [--wait] [-o DIR]  # plan a scene on the service (neuenh scene plan)

The service is ``--url`` or ``$NEUENH_URL`` (default http://127.0.0.1:8000); its token ``--token``
or ``$NEUENH_API_TOKEN`` (prefer the variable: flags show in ``ps``). ``--json`` prints what the
service answered, for machines; people get tables and a progress display (on stderr).

Exit codes (DESIGN §4): 0 success, 1 the job failed (or was cancelled) or the service failed,
2 usage error (a bad spec or table, no such job, a request the service refuses), 3 the service
cannot be reached or does not accept the token. Every error is one line, never a traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
from datetime import datetime
from pathlib import Path

from .client_api import DEFAULT_URL, READ_TIMEOUT_S, Api, ClientError
from .client_download import check_target, default_target, save_model
from .client_follow import follow, outcome

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
DOWNLOAD_TIMEOUT_S = 300.0
FIT_TIMEOUT_S = 3600.0


def build_parser() -> argparse.ArgumentParser:
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--url", default=argparse.SUPPRESS,
                        help=f"the service (default: $NEUENH_URL or {DEFAULT_URL})")
    common.add_argument("--token", default=argparse.SUPPRESS,
                        help="its bearer token (default: $NEUENH_API_TOKEN, which ps does not show)")
    common.add_argument("--timeout", type=float, default=argparse.SUPPRESS, metavar="SECONDS",
                        help=f"how long to wait for an answer (default {READ_TIMEOUT_S:g}; "
                             "download and fit wait longer)")
    parser = argparse.ArgumentParser(prog="neuenh-client", parents=[common], description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def command(name, run, help, aliases=()):
        p = commands.add_parser(name, parents=[common], help=help, description=help, aliases=list(aliases))
        p.set_defaults(run=run, command=name)
        return p

    def job_arg(p):
        p.add_argument("job", metavar="JOB", help="the job id")

    def json_arg(p, what="print the service's answer as JSON"):
        p.add_argument("--json", action="store_true", help=what)

    def follow_args(p):
        p.add_argument("--interval", type=float, default=0.5, metavar="SECONDS", help="how often to poll (default 0.5)")
        p.add_argument("--reconnect", type=float, default=60.0, metavar="SECONDS",
                       help="how long to wait out a service that went away, e.g. restarting (default 60)")

    p = command("submit", submit, "submit a search job (a spec file, flags, or both)")
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

    p = command("status", status, "a job's status, or without JOB the service's health, cluster and recent jobs")
    p.add_argument("job", metavar="JOB", nargs="?", help="the job id")
    json_arg(p)

    p = command("jobs", jobs, "list jobs, newest first", aliases=("list",))
    p.add_argument("--status", action="append", type=str.upper, metavar="STATUS",
                   help="only jobs in this status (repeatable): QUEUED, PREPARING, RUNNING, CONVERGED, ...")
    p.add_argument("--limit", type=int, default=20, help="at most this many (default 20)")
    json_arg(p)

    p = command("history", history, "a job's committed rounds: +X made position X neural, -X analytical again")
    job_arg(p)
    p.add_argument("--since", type=int, default=0, metavar="ROUND", help="only rounds from this one on")
    json_arg(p, "print the service's history (every candidate of every round) as JSON")

    p = command("watch", watch, "follow a job until it ends (Ctrl-C stops watching, not the job)")
    job_arg(p)
    json_arg(p, "print the finished job as JSON")
    follow_args(p)

    p = command("cancel", cancel, "cancel an unfinished job (it keeps its committed rounds)")
    job_arg(p)
    json_arg(p)

    p = command("download", download, "download a job's model (its last committed round)")
    job_arg(p)
    p.add_argument("-o", "--output", type=Path, metavar="DIR|FILE.zip",
                   help="a directory to extract the bundle into (default ./neuenh-JOB), or a .zip to keep the archive")
    p.add_argument("--force", action="store_true", help="replace an existing non-empty directory or zip")
    json_arg(p, "print what was saved as JSON")

    p = command("export", export_job, "a job's model and materials in a renderer's format (GLSL, ONNX, Mitsuba 3)")
    job_arg(p)
    p.add_argument("--format", required=True, choices=("glsl", "onnx", "mitsuba"), help="what to write")
    p.add_argument("-o", "--output", type=Path, metavar="DIR", help="where to extract the files (default ./neuenh-JOB-FORMAT)")
    p.add_argument("--material", action="append", metavar="NAME", help="only this material (repeat); default all")
    p.add_argument("--force", action="store_true", help="write into an existing non-empty directory")

    p = command("fit", fit, "fit measured materials with a job's model on the service (module weights frozen)")
    job_arg(p)
    p.add_argument("tables", nargs="+", type=Path, metavar="MEASUREMENTS",
                   help="one table per material (.npz with wi, wo, f_r, or CSV wi_x..wo_z,r,g,b)")
    p.add_argument("--method", choices=("fast", "paper"), default="fast",
                   help="fast (default): Adam with cosine decay; paper: RMSProp lr 1e-3, 1000 epochs")
    p.add_argument("--epochs", type=int, help="override the method's epoch count")
    json_arg(p)

    p = command("plan", plan, "plan a scene on the service: per material the cheapest model within tolerance")
    p.add_argument("scene", type=Path, metavar="SCENE.yaml",
                   help="a scene (neuenh scene plan's format); its files are read by the service, under its data "
                        "roots, unless --upload sends them")
    p.add_argument("--upload", action="store_true",
                   help="send the scene's measured files (tables, RGL .bsdf, MERL .binary) with it, for a service "
                        "that cannot read them where they are")
    p.add_argument("--wait", action="store_true", help="follow the plan until it ends; exit 1 if it failed")
    p.add_argument("-o", "--output", type=Path, metavar="DIR", help="with --wait: save the plan's files here")
    p.add_argument("--idempotency-key", metavar="KEY", help="submitting again with the same key returns the same plan")
    p.add_argument("--interval", type=float, default=1.0, metavar="SECONDS", help="how often to poll (default 1)")
    json_arg(p, "print the plan as JSON")
    return parser


# -- commands ---------------------------------------------------------------------------------
def submit(args, api: Api) -> int:
    spec = _spec(args)
    job, created = api.submit(spec, args.idempotency_key)
    if not args.json:
        print(job["id"], flush=True)
    _note(f"job {job['id']} {'submitted' if created else 'already submitted with this key'} "
          f"({job['status'].lower()})")
    if not args.wait:
        if args.json:
            _print_json(job)
        else:
            _note(f"follow it with: neuenh-client watch {job['id']}")
        return 0
    return _follow(api, job["id"], args)


def watch(args, api: Api) -> int:
    return _follow(api, args.job, args)


def status(args, api: Api) -> int:
    if args.job:
        job = api.job(args.job)
        print(json.dumps(job, indent=2) if args.json else _job_text(job))
        return 0
    health = api.health()
    cluster = api.cluster()
    recent = api.jobs(limit=10)
    if args.json:
        _print_json({"url": api.url, "health": health, "cluster": cluster, "jobs": recent})
        return 0
    print(f"service {api.url}: {health['status']} (neuenh {health['version']}, worker "
          f"{'alive' if health['worker_alive'] else 'down'}, auth {'on' if health['auth'] else 'off'})")
    for job_id, why in (health.get("broken_jobs") or {}).items():
        print(f"broken job {job_id}: {why}")
    if cluster is not None:
        print(f"cluster: {cluster['backend']}{' at ' + cluster['address'] if cluster.get('address') else ''}, "
              f"{len(cluster['nodes'])} node(s), {cluster['cpus']:g} CPUs ({cluster['cpus_available']:g} free), "
              f"{cluster['gpus']:g} GPUs, {cluster['busy_candidates']} candidate(s) training; "
              f"{len(cluster['running_jobs'])} of at most {cluster['max_running_jobs']} job(s) running")
        for holder in cluster["holders"]:
            print(f"  job {holder['job_id']}: {holder['candidates']} candidate(s), {holder['cpus']:g} CPUs"
                  + (f", {holder['gpus']:g} GPUs" if holder["gpus"] else ""))
    print(_jobs_table(recent) if recent else "no jobs yet")
    return 0


def jobs(args, api: Api) -> int:
    found = api.jobs(args.status, limit=max(args.limit, 1))
    if args.json:
        _print_json(found)
    elif found:
        print(_jobs_table(found))
    else:
        _note("no jobs" + (f" in status {', '.join(args.status)}" if args.status else ""))
    return 0


def history(args, api: Api) -> int:
    data = api.history(args.job, args.since)
    if args.json:
        _print_json(data)
        return 0
    if not data["rounds"]:
        _note(f"job {args.job} has no committed round{' from ' + str(args.since) if args.since else ''} yet "
              f"({data['status'].lower()})")
        return 0
    print(_history_table(data["rounds"]))
    return 0


def cancel(args, api: Api) -> int:
    job = api.cancel(args.job)
    if args.json:
        _print_json(job)
    else:
        rounds = 0 if job["last_round"] is None else job["last_round"] + 1
        print(f"job {job['id']}: {job['status']} (it keeps its {rounds} committed round(s))")
    return 0


def download(args, api: Api) -> int:
    target = args.output or default_target(args.job)
    check_target(target, args.force)
    r = api.model(args.job, read_timeout=args.timeout or DOWNLOAD_TIMEOUT_S)
    bundle = save_model(r.content, target, args.force)
    saved = {"job_id": args.job, "round": int(r.headers.get("X-Neuenh-Round", -1)),
             "state": bundle.model.state, "path": str(target)}
    if args.json:
        _print_json(saved)
    else:
        print(target)
        _note(f"job {args.job} round {saved['round']} (state {saved['state']}) saved to {target}")
    return 0


def export_job(args, api: Api) -> int:
    import io
    import zipfile

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


def fit(args, api: Api) -> int:
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
        _print_json(report)
    else:
        from .fit import _table

        print(f"job {report['job_id']} round {report['round']}: {_table(report)}")
    return 0


def plan(args, api: Api) -> int:
    import time

    from neuenh.scene import load_scene

    spec, base = load_scene(args.scene)  # a bad scene is a usage error before the service is contacted
    scene = _service_paths(spec.model_dump(mode="json", exclude_none=True), base)
    if args.upload:
        scene, paths = _uploaded(scene)
        with contextlib.ExitStack() as stack:
            files = [(p.name, stack.enter_context(open(p, "rb"))) for p in paths]
            found, created = api.submit_plan_with_files(scene, files, args.idempotency_key,
                                                        read_timeout=args.timeout or DOWNLOAD_TIMEOUT_S)
    else:
        found, created = api.submit_plan(scene, args.idempotency_key)
    _note(f"plan {found['id']} {'submitted' if created else 'already submitted with this key'} "
          f"({found['status'].lower()})")
    if not args.wait:
        print(json.dumps(found, indent=2) if args.json else found["id"])
        return 0
    last = None
    while not found["terminal"]:
        progress = found.get("progress")
        line = (f"plan {found['id']}: {found['materials_done']}/{found['materials_total'] or '?'} materials"
                + (f", {progress['step']}/{progress['steps']} fits ({progress['message']})" if progress else ""))
        if line != last:
            _note(line)
            last = line
        time.sleep(max(args.interval, 0.05))
        found = api.plan(found["id"])
    if args.output and found["status"] == "DONE":
        args.output.mkdir(parents=True, exist_ok=True)
        for name in found["files"]:
            (args.output / name).write_bytes(api.plan_file(found["id"], name))
    if args.json:
        _print_json(found)
    elif found["status"] == "DONE":
        result = found["plan"]
        labels = {r["key"]: r["label"] for r in result["ladder"]}
        print(_table([("material", "chosen rung", "error", "cost (ns)")]
                     + [(m["name"], labels[m["chosen"]][:40], f"{m['error']:.4f}", f"{m['cost_ns']:.0f}")
                        for m in result["materials"]], right=(2, 3)))
        t = result["totals"]
        print(f"frame: plan {t['plan']['cost_ns']:.0f} ns, error {t['plan']['error']:.4f} | richest everywhere "
              f"{t['richest']['cost_ns']:.0f} ns, {t['richest']['error']:.4f} | cheapest everywhere "
              f"{t['cheapest']['cost_ns']:.0f} ns, {t['cheapest']['error']:.4f}")
        if args.output:
            _note(f"saved {', '.join(found['files'])} to {args.output}")
    else:
        _note(f"plan {found['id']}: FAILED: {found['error']}")
    return 0 if found["status"] == "DONE" else 1


# -- helpers ----------------------------------------------------------------------------------
def _service_paths(scene: dict, base: Path) -> dict:
    """A scene's relative paths that name files beside it here, made absolute: the service resolves
    relative paths against its own working directory (a service on this machine then reads the same
    files; for one elsewhere, write the paths it sees)."""
    def fix(path: str) -> str:
        here = base / path
        return str(here.resolve()) if not Path(path).is_absolute() and here.exists() else path

    for m in scene["materials"]:
        for key in ("path", "capture"):
            if key in m:
                m[key] = fix(m[key])
    scene["ladder"] = [fix(r) if isinstance(r, str) and ("/" in r or (base / r).is_dir()) else
                       ({"rungs": fix(r["rungs"])} if isinstance(r, dict) and "/" in r["rungs"] else r)
                       for r in scene["ladder"]]
    return scene


def _uploaded(scene: dict) -> tuple[dict, list[Path]]:
    """The scene with each measured file named by its file name alone, and the files to send; a
    capture (a folder of texels) is not sent: one line says so."""
    paths: list[Path] = []
    for i, m in enumerate(scene["materials"]):
        if "capture" in m:
            raise ValueError(f"materials.{i}: a capture ({m['capture']}) cannot be uploaded; put it under the "
                             "service's data roots and plan without --upload")
        path = Path(m["path"])
        if not path.is_file():
            raise ValueError(f"materials.{i}: {path}: no such file to upload")
        clash = next((p for p in paths if p.name == path.name), None)
        if clash is not None:
            raise ValueError(f"materials.{i}: {path} and {clash} share the file name {path.name!r}; rename one "
                             "to upload both")
        paths.append(path)
        m["path"], m["name"] = path.name, m.get("name") or path.stem
    return scene, paths


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


def _spec(args) -> dict:
    """The spec to send: the file's (or the quickstart's) with the flags applied, validated here so
    a bad one is a usage error before the service is contacted."""
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


def _follow(api: Api, job_id: str, args) -> int:
    try:
        job = follow(api, job_id, sys.stderr, interval=args.interval, reconnect_s=args.reconnect)
    except KeyboardInterrupt:
        _note(f"stopped watching job {job_id}; it keeps running on the service "
              f"(neuenh-client cancel {job_id} stops it)")
        return 130
    code, line = outcome(job)
    _note(line)
    if args.json:
        _print_json(job)
    return code


def _history_table(rounds: list[dict]) -> str:
    """One row per round with the change and the gain the service describes (as the dashboard);
    the winner's fit score beside its val loss when the job scored candidates on held-out materials."""
    fit = any(r.get("winner_fit_score") is not None for r in rounds)
    rows = [("round", "parent -> winner", "changed", "val loss", *(("fit score",) if fit else ()), "vs start",
             "ok/total", "wall")]
    for r in rounds:
        ok = f"{sum(c['ok'] for c in r['candidates'])}/{len(r['candidates'])}"
        ok += f" ({r['recovered']} recovered)" if r.get("recovered") else ""
        gain = "-" if r["gain_over_start"] is None else f"{-100 * r['gain_over_start']:+.1f}%"
        score = "-" if r.get("winner_fit_score") is None else f"{r['winner_fit_score']:.5f}"
        rows.append((str(r["round"]) + (" polish" if r["kind"] == "polish" else ""),
                     f"{r['parent_state']} -> {r['winner_state']}",
                     r["change"] + (" converged" if r["converged"] else ""),
                     f"{r['winner_val_loss']:.5f}", *((score,) if fit else ()), gain, ok, f"{r['wall_s']:.1f}s"))
    return _table(rows, right=tuple(i for i, h in enumerate(rows[0]) if h not in ("parent -> winner", "changed")))


def _jobs_table(found: list[dict]) -> str:
    rows = [("id", "status", "rounds", "state", "model", "name", "created")]
    for j in found:
        rows.append((j["id"], _status(j), str(0 if j["last_round"] is None else j["last_round"] + 1),
                     j["current_state"] or "-", j["model"], j["name"] or "-", _local(j["created_at"])))
    return _table(rows, right=(2,))


def _job_text(job: dict) -> str:
    rounds = 0 if job["last_round"] is None else job["last_round"] + 1
    lines = [f"job {job['id']}" + (f" ({job['name']})" if job["name"] else ""),
             f"  status     {_status(job)}", f"  model      {job['model']}",
             f"  rounds     {rounds} committed" + (f", state {job['current_state']}" if job["current_state"] else "")]
    p = job.get("progress")
    if p:
        best = f"{p['best_val_loss']:.5f}" if p["best_val_loss"] is not None else "-"
        lines.append(f"  progress   round {p['round']}  candidates {p['done']}/{p['total']}  best {best}  "
                     f"{p['message']}".rstrip())
    if job["error"]:
        lines.append(f"  error      {job['error']}")
    limits = job["spec"].get("budget") or {}
    for what, used, key in (("wall", job["used_wall_s"], "wall_s"), ("cpu", job["used_cpu_s"], "cpu_s")):
        of = f" of a {limits[key]:g} s budget" if limits.get(key) else ""
        lines.append(f"  used {what:<5} {used:.1f} s{of}")
    lines += [f"  created    {_local(job['created_at'])}", f"  updated    {_local(job['updated_at'])}"]
    return "\n".join(lines)


def _status(job: dict) -> str:
    return job["status"] + (f" ({job['reason']})" if job.get("reason") else "")


def _table(rows: list[tuple[str, ...]], right=()) -> str:
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return "\n".join("  ".join(c.rjust(w) if i in right else c.ljust(w) for i, (c, w) in enumerate(zip(r, widths))).rstrip()
                     for r in rows)


def _local(stamp: str) -> str:
    return datetime.fromisoformat(stamp).astimezone().strftime("%Y-%m-%d %H:%M:%S")


def _print_json(data) -> None:
    print(json.dumps(data, indent=2))


def _note(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


# -- entry point ------------------------------------------------------------------------------
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    prefix = f"neuenh-client {args.command}"
    args.timeout = getattr(args, "timeout", None)  # None: each call's own default
    url = getattr(args, "url", None) or os.environ.get("NEUENH_URL") or DEFAULT_URL
    token = getattr(args, "token", None) or os.environ.get("NEUENH_API_TOKEN") or None
    try:
        api = Api(url, token, read_timeout=args.timeout or READ_TIMEOUT_S)
        try:
            return args.run(args, api)
        finally:
            api.close()
    except BrokenPipeError:
        # The reader went away (`neuenh-client history JOB | head`): stop quietly, as SIGPIPE would.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except ClientError as exc:
        print(f"{prefix}: error: {exc}", file=sys.stderr)
        return exc.code
    except (ValueError, OSError) as exc:  # a bad spec or table (SpecError, TableError), a file not there
        print(f"{prefix}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{prefix}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
