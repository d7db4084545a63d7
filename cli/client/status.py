"""``neuenh-client status [JOB]``: a job's status, or without JOB the service's health, its cluster
and the recent jobs."""

from __future__ import annotations

import json

from .api import Api
from .commands import Commands, job_status, json_arg, local_time, print_json, rounds_committed
from .jobs import jobs_table


def add_parser(commands: Commands) -> None:
    p = commands.add("status", run, "a job's status, or without JOB the service's health, cluster and recent jobs")
    p.add_argument("job", metavar="JOB", nargs="?", help="the job id")
    json_arg(p)


def run(args, api: Api) -> int:
    if args.job:
        job = api.job(args.job)
        print(json.dumps(job, indent=2) if args.json else job_text(job))
        return 0
    health = api.health()
    cluster = api.cluster()
    recent = api.jobs(limit=10)
    if args.json:
        print_json({"url": api.url, "health": health, "cluster": cluster, "jobs": recent})
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
    print(jobs_table(recent) if recent else "no jobs yet")
    return 0


def job_text(job: dict) -> str:
    """A job as a block of ``name  value`` lines: status, model, rounds, progress, usage, times."""
    lines = [f"job {job['id']}" + (f" ({job['name']})" if job["name"] else ""),
             f"  status     {job_status(job)}", f"  model      {job['model']}",
             f"  rounds     {rounds_committed(job)} committed"
             + (f", state {job['current_state']}" if job["current_state"] else "")]
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
    lines += [f"  created    {local_time(job['created_at'])}", f"  updated    {local_time(job['updated_at'])}"]
    return "\n".join(lines)
