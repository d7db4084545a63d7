"""Shared-cluster benchmark (issue 18): three radius-1 jobs one after another against the same three
jobs at once, on the compose emulation's two one-CPU worker nodes.

    .venv/bin/python bench/bench_shared_cluster.py --write docs/BENCHMARKS.md

The stack is docker-compose.yml run as local processes by ``tests/deploy/compose_local.py`` (as
tests/deploy/test_compose.py runs it): a Ray head without CPUs, two ``ray start`` worker nodes of
one CPU each, moto's S3 server in place of MinIO, and the api (``neuenh serve`` joining the cluster
through RAY_ADDRESS). The cluster stays up; the api is started once per mode, each time with its
own data directory, S3 prefix (no dataset cached by the other mode) and Ray job (fresh worker
processes):

* **one after another**: ``NEUENH_MAX_RUNNING_JOBS=1``, the three jobs submitted together, so the
  queue runs them in turn;
* **together**: ``NEUENH_MAX_RUNNING_JOBS=3``, the same three jobs sharing the two slots
  (orchestrator/shares.py).

Each job is a small GGX search at radius 1 (12 candidates a round) with its own train and data
seeds. ``GET /v1/cluster`` is sampled every ``--sample-s`` seconds from the first submission until
the last job ends: Ray's slots in use (``cpus - cpus_available``) and each job's candidates in
flight (``holders``). Utilisation is the time-weighted mean of slots in use / slots over that
window; "both busy" the share of the window with both slots in use. The plot (docs/img/) shows the
slots in use over time and, stacked, each job's candidates in flight.
"""

from __future__ import annotations

import argparse
import os
import secrets
import sys
import time
from pathlib import Path

import httpx
import ray

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests"), str(ROOT / "tests" / "deploy")]
from bench.harness import Background, machine, wait_quiet  # noqa: E402
from bench.report import publish  # noqa: E402
from compose_local import LocalCompose, processes_mentioning  # noqa: E402
from s3_server import MOTO_SERVER  # noqa: E402

SECTION = "## Concurrent jobs on a shared cluster (issue 18)"
PLOT = ROOT / "docs" / "img" / "shared_cluster.png"
COMPOSE = ROOT / "docker-compose.yml"
ENV = {  # what an operator puts in .env (as in tests/deploy/test_compose.py)
    "RAY_AUTH_TOKEN": secrets.token_hex(16),
    "S3_SECRET_KEY": "bench-secret-key",
    "NEUENH_API_TOKEN": "bench-token",
    "NEUENH_WORKER_CPUS": "1",  # two nodes of one CPU each: the machine has two cores
    "NEUENH_WORKER_OBJECT_STORE_BYTES": str(200 << 20),
    "NEUENH_API_OBJECT_STORE_BYTES": str(200 << 20),
}
MODES = (("one after another", 1), ("together", 3))


def job_spec(i: int, args: argparse.Namespace) -> dict:
    return {
        "name": f"bench-{i}", "model": "ggx",
        "search": {"radius": 1, "epochs_per_round": args.epochs, "max_rounds": args.rounds},
        "train": {"lr": 5.0e-3, "batch_size": 4096, "seed": 100 + i},
        "data": [{"source": "synthetic_zoo", "materials": args.materials, "samples": args.samples,
                  "seed": 10 + i}],
    }


def start_cluster(stack: LocalCompose) -> None:
    """Object store and bucket, Ray head, two worker nodes (tests/deploy/test_compose.py's order)."""
    stack.replace("object-store", [MOTO_SERVER, "-H", "127.0.0.1", "-p", str(stack.port("object-store", 9000))])
    stack.start("object-store")
    deadline = time.monotonic() + 30
    while stack.run("create-bucket").returncode != 0:
        if time.monotonic() > deadline:
            raise RuntimeError("the bucket could not be created")
        time.sleep(0.5)
    stack.start("ray-head")
    stack.healthy("ray-head", timeout=60)
    for replica in (0, 1):
        stack.start("ray-worker", replica)
        stack.wait_log(f"ray-worker-{replica}", "Ray runtime started", timeout=60)


def stack_cpu_s(stack: LocalCompose, replica: int) -> dict[str, float]:
    """CPU seconds used so far by the stack's live processes (found by their directory), by part:
    the api (``neuenh serve`` and its Ray node, plus this bench), the worker nodes (raylets and the
    processes training candidates) and the rest (head, S3 server)."""
    tick = os.sysconf("SC_CLK_TCK")

    def cpu(pids: set[int]) -> float:
        total = 0.0
        for pid in pids:
            try:
                fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
                total += (int(fields[11]) + int(fields[12])) / tick
            except (OSError, IndexError, ValueError):
                pass
        return total

    every = processes_mentioning(str(stack.root) + "/")
    api = processes_mentioning(str(stack.root / f"api-{replica}") + "/") & every
    workers = set().union(*(processes_mentioning(str(stack.root / f"ray-worker-{i}") + "/") for i in (0, 1))) & every
    return {"api": cpu(api) + sum(os.times()[:2]), "workers": cpu(workers),
            "rest": cpu(every - api - workers)}


def run_mode(stack: LocalCompose, replica: int, max_running: int, specs: list[dict], sample_s: float) -> dict:
    data_dir = stack.root / f"api-data-{replica}"
    data_dir.mkdir()
    stack.start("api", replica, env={"NEUENH_MAX_RUNNING_JOBS": str(max_running),
                                     "NEUENH_S3_PREFIX": f"mode-{replica}"},
                paths={"/var/lib/neuenh": data_dir})
    try:
        stack.healthy("api", timeout=120)
        headers = {"Authorization": f"Bearer {ENV['NEUENH_API_TOKEN']}"}
        with httpx.Client(base_url=stack.url("api", 8000) + "/v1", headers=headers, timeout=30) as api:
            assert api.get("/cluster").json()["max_running_jobs"] == max_running
            wait_quiet(max_wait=30, threshold=0.5)
            machine_cpu, stack_cpu = Background._busy(), stack_cpu_s(stack, replica)
            t0 = time.monotonic()
            ids = []
            for spec in specs:
                r = api.post("/jobs", json=spec)
                r.raise_for_status()
                ids.append(r.json()["id"])
            # A job ends at the first sample that no longer lists it running; its status is read
            # then (and every second, in case it ended between two samples).
            samples, seen, left, terminal, last_check = [], set(), {}, set(), 0.0
            while len(terminal) < len(ids):
                t = time.monotonic() - t0
                c = api.get("/cluster").json()
                running = set(c["running_jobs"])
                samples.append({"t": t, "used": c["cpus"] - c["cpus_available"], "cpus": c["cpus"],
                                "in_flight": {h["job_id"]: h["candidates"] for h in c["holders"]},
                                "running": sorted(running)})
                for job_id in seen - running - set(left):
                    left[job_id] = t
                seen |= running
                if set(left) - terminal or t - last_check >= 1.0:
                    last_check = t
                    terminal |= {j["id"] for j in api.get("/jobs").json()["jobs"] if j["terminal"] and j["id"] in ids}
                if t > 900:
                    raise RuntimeError(f"jobs still running after 900 s: {len(terminal)} of {len(ids)} ended")
                time.sleep(max(0.0, sample_s - (time.monotonic() - t0 - t)))
            elapsed = time.monotonic() - t0
            busy, after = Background._busy() - machine_cpu, stack_cpu_s(stack, replica)
            cores = {part: (after[part] - stack_cpu[part]) / elapsed for part in after}
            background = max(0.0, busy / elapsed - sum(cores.values()))
            ended = {job_id: left.get(job_id, elapsed) for job_id in ids}
            wall = max(ended.values())
            jobs = []
            for job_id in ids:
                job = api.get(f"/jobs/{job_id}").json()
                rounds = api.get(f"/jobs/{job_id}/history").json()["rounds"]
                started = next((s["t"] for s in samples if job_id in s["running"]), 0.0)
                candidates = [c for r in rounds for c in r["candidates"]]
                jobs.append({"id": job_id, "name": job["name"], "status": job["status"], "rounds": len(rounds),
                             "candidates": len(candidates), "failed": sum(not c["ok"] for c in candidates),
                             "train_s": sum(c["wall_s"] for c in candidates),
                             "started": started, "ended": ended[job_id]})
    finally:
        stack.kill_node(f"api-{replica}")
        stack.procs.pop(f"api-{replica}")  # gone: the next replica's health check must not see it
    return {"max_running": max_running, "wall": wall, "samples": samples, "jobs": jobs,
            "background": background, "cores": cores, **utilisation(samples, wall)}


def utilisation(samples: list[dict], wall: float) -> dict:
    """Time-weighted over [0, wall]: each sample holds until the next one."""
    busy = both = 0.0
    for s, nxt in zip(samples, samples[1:] + [{"t": wall}]):
        dt_ = max(0.0, min(nxt["t"], wall) - s["t"])
        used = min(s["used"], s["cpus"])
        busy += dt_ * used / s["cpus"]
        both += dt_ * (used >= s["cpus"] - 1e-9)
    gaps = [b["t"] - a["t"] for a, b in zip(samples, samples[1:])]
    return {"utilisation": busy / wall, "both_busy": both / wall,
            "mean_interval": sum(gaps) / max(1, len(gaps))}


def max_in_flight(r: dict) -> int:
    return max(sum(s["in_flight"].values()) for s in r["samples"])


def plot(results: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(results), 1, figsize=(12, 2.6 * len(results)), sharex=True)
    colours = ["#4c72b0", "#dd8452", "#55a868"]
    span = max(r["wall"] for r in results)
    for i, (ax, r) in enumerate(zip(axes, results), 1):
        t = [s["t"] for s in r["samples"]]
        names = {j["id"]: j["name"] for j in r["jobs"]}
        stacks = [[s["in_flight"].get(job_id, 0) for s in r["samples"]] for job_id in names]
        ax.stackplot(t, stacks, labels=[f"{n}: candidates in flight" for n in names.values()],
                     colors=colours, alpha=0.55, step="post")
        ax.step(t, [s["used"] for s in r["samples"]], where="post", color="black", lw=1.2,
                label="Ray slots in use")
        ax.axhline(2, color="grey", ls="--", lw=0.8)
        top = max(max(sum(s["in_flight"].values()), s["used"]) for s in r["samples"])
        ax.set_ylim(0, top + 0.3)
        ax.set_xlim(0, span * 1.02)
        ax.set_ylabel("slots / candidates")
        ax.set_title(f"run {i}, {r['label']} (NEUENH_MAX_RUNNING_JOBS={r['max_running']}): {r['wall']:.0f} s, "
                     f"mean slots busy {r['utilisation']:.0%}, both busy {r['both_busy']:.0%} of the time",
                     fontsize=10)
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    axes[-1].set_xlabel("seconds since the three jobs were submitted")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)


def run_table(results: list[dict]) -> list[str]:
    lines = ["| run | mode | NEUENH_MAX_RUNNING_JOBS | wall, all jobs (s) | utilisation | both slots busy | "
             "candidate training, summed (s) | per candidate (s) | CPU: worker nodes | CPU: api | "
             "CPU: head, S3 | CPU: other work |",
             "|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for i, r in enumerate(results, 1):
        lines.append(f"| {i} | {r['label']} | {r['max_running']} | {r['wall']:.1f} | {r['utilisation']:.1%} | "
                     f"{r['both_busy']:.1%} | {r['train_s']:.1f} | {r['per_candidate_s']:.2f} | "
                     f"{r['cores']['workers']:.2f} | {r['cores']['api']:.2f} | {r['cores']['rest']:.2f} | "
                     f"{r['background']:.2f} |")
    return lines


def job_table(results: list[dict]) -> list[str]:
    lines = ["| run | mode | job | rounds | candidates (failed) | status | started (s) | ended (s) | running (s) |",
             "|---:|---|---|---:|---:|---|---:|---:|---:|"]
    for i, r in enumerate(results, 1):
        for j in r["jobs"]:
            lines.append(f"| {i} | {r['label']} | {j['name']} | {j['rounds']} | {j['candidates']} ({j['failed']}) | "
                         f"{j['status']} | {j['started']:.1f} | {j['ended']:.1f} | {j['ended'] - j['started']:.1f} |")
    return lines


def mean(values) -> float:
    values = list(values)
    return sum(values) / len(values)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--jobs", type=int, default=3)
    parser.add_argument("--rounds", type=int, default=4, help="max_rounds of each job")
    parser.add_argument("--epochs", type=int, default=10, help="epochs_per_round of each job")
    parser.add_argument("--materials", type=int, default=16, help="synthetic_zoo materials of each job")
    parser.add_argument("--samples", type=int, default=4000, help="samples per material")
    parser.add_argument("--pairs", type=int, default=2, help="runs of each mode, in the order AB BA AB ... "
                                                             "(so a drift of the machine's load favours neither)")
    parser.add_argument("--sample-s", type=float, default=0.2, help="seconds between /v1/cluster samples")
    parser.add_argument("--write", metavar="PATH", help="write/replace this section of PATH (and the plot)")
    args = parser.parse_args()
    specs = [job_spec(i, args) for i in range(args.jobs)]
    order = [m for p in range(args.pairs) for m in (MODES if p % 2 == 0 else MODES[::-1])]
    env = machine()
    waited = wait_quiet(max_wait=60, threshold=0.3)
    load_before = os.getloadavg()
    stack = LocalCompose(COMPOSE, ENV, {"ray-head": [6379], "object-store": [9000], "api": [8000]})
    results = []
    try:
        start_cluster(stack)
        for replica, (label, max_running) in enumerate(order):
            r = run_mode(stack, replica, max_running, specs, args.sample_s)
            r["label"] = label
            r["train_s"] = sum(j["train_s"] for j in r["jobs"])
            r["per_candidate_s"] = r["train_s"] / max(1, sum(j["candidates"] for j in r["jobs"]))
            results.append(r)
            print(f"{label}: {r['wall']:.1f} s, utilisation {r['utilisation']:.3f}, both busy "
                  f"{r['both_busy']:.3f}, per candidate {r['per_candidate_s']:.2f} s, cpu {r['cores']}, "
                  f"background {r['background']:.2f} cores, jobs {r['jobs']}", flush=True)
    finally:
        stack.close()
    load_after = os.getloadavg()
    seq = [r for r in results if r["max_running"] == 1]
    conc = [r for r in results if r["max_running"] > 1]
    if args.write:
        plot(results, PLOT)

    s = specs[0]
    wall_seq, wall_conc = mean(r["wall"] for r in seq), mean(r["wall"] for r in conc)
    per_cand = {k: mean(r["per_candidate_s"] for r in rs) for k, rs in (("seq", seq), ("conc", conc))}
    slot_s = {k: mean(r["utilisation"] * 2 * r["wall"] for r in rs) for k, rs in (("seq", seq), ("conc", conc))}
    lines = [
        SECTION, "",
        "Command: `.venv/bin/python bench/bench_shared_cluster.py --write docs/BENCHMARKS.md`  ",
        f"Date: {env['date']}; 2-core {env['cpu']}, torch {env['torch']}, Ray {ray.__version__}; git {env['git']}  ",
        f"Load average (1, 5, 15 min): {', '.join(f'{x:.2f}' for x in load_before)} at the start (after "
        f"waiting {waited:.0f} s for a quiet machine), {', '.join(f'{x:.2f}' for x in load_after)} at the "
        "end: the machine is shared (another engineer's tests ran meanwhile), see *CPU: other work*.",
        "",
        "The compose emulation (`tests/deploy/compose_local.py`: docker-compose.yml's commands as local "
        "processes; a Ray head with 0 CPUs, two `ray start` worker nodes of 1 CPU each, moto in place of "
        "MinIO) stays up; the api is started for each run with `NEUENH_MAX_RUNNING_JOBS` 1 (*one after "
        "another*: the queue runs the jobs in turn) or 3 (*together*: they share the two slots through "
        "orchestrator/shares.py), each time with its own data directory, S3 prefix and Ray job. The runs "
        f"alternate (order {' '.join('A' if m[1] == 1 else 'B' for m in order)}, A = one after another) so "
        f"a drift of the machine's load favours neither. Each run submits the same {args.jobs} jobs at "
        f"once: GGX at radius 1 (12 candidates a round), up to {s['search']['max_rounds']} rounds of "
        f"{s['search']['epochs_per_round']} epochs, synthetic_zoo {args.materials} materials × "
        f"{args.samples} samples, batch 4096, each its own train and data seed. `GET /v1/cluster` sampled "
        f"every {args.sample_s} s (measured: every {mean(r['mean_interval'] for r in results):.2f} s) "
        "from the first submission to the last job's end; *slots in use* = `cpus - cpus_available` "
        "(Ray's view, 2 slots); *utilisation* its time-weighted mean / 2; *both busy* the share of that "
        "time with both slots in use. *CPU* columns: mean cores used over the run, from /proc: the worker "
        "nodes (raylets and the processes training candidates), the api (`neuenh serve`, its Ray node, "
        "this bench's polling), the Ray head and moto, and *other work* (the machine's busy time minus "
        "all of these).",
        "",
        *run_table(results),
        "",
        *job_table(results),
        "",
        f"- Wall time of the three jobs, mean of {args.pairs} run(s) each: **together {wall_conc:.1f} s, one "
        f"after another {wall_seq:.1f} s; one after another / together = {wall_seq / wall_conc:.2f}** "
        f"({'less' if wall_conc < wall_seq else 'more'} wall time by {abs(1 - wall_conc / wall_seq):.0%}). "
        f"Utilisation **{mean(r['utilisation'] for r in conc):.1%}** together against **{mean(r['utilisation'] for r in seq):.1%}**; "
        f"both slots busy {mean(r['both_busy'] for r in conc):.0%} of the time against {mean(r['both_busy'] for r in seq):.0%}.",
        f"- Slot-seconds in use (utilisation × 2 × wall): {slot_s['conc']:.0f} together, {slot_s['seq']:.0f} "
        f"one after another, for the same candidates: a candidate took {per_cand['conc']:.2f} s together "
        f"against {per_cand['seq']:.2f} s ({per_cand['conc'] / per_cand['seq'] - 1:+.0%}). The slots are "
        "Ray's bookkeeping, not cores: the two training processes share the machine's 2 cores with the "
        "api, the head, moto and other work (the *CPU* columns), so a slot kept busy more of the time "
        "does not by itself buy wall time.",
        f"- Candidates in flight (`holders`, submitted to Ray, summed over the jobs) reached at most "
        f"{max(max_in_flight(r) for r in seq)} one after another and {max(max_in_flight(r) for r in conc)} "
        "together, over the 2 slots: every running job may keep one candidate in flight whatever its "
        "share (with 3 jobs on 2 slots, one each, so one waits in Ray's queue) and a job over its share "
        "keeps what it already submitted (nothing is pre-empted: the jobs' first candidates go out "
        "before all three jobs have registered with FairShare); the slots in use never exceed 2.",
        "- What concurrency can win on 2 slots is only the idle slot: one job alone keeps both slots "
        "busy while a round has two or more candidates left, so the gain is limited to each round's "
        "tail (the last or longest candidate on one slot while the other waits), the gap between "
        "rounds (selection, checkpoint to S3, the next round's bundles) and each job's start (dataset, "
        "Ray's worker processes); one after another that idle time is "
        f"{1 - mean(r['utilisation'] for r in seq):.0%} of the slot time. The training work is the same in both modes.",
    ]
    if args.write:
        lines += ["", f"![slots in use over time, each run](img/{PLOT.name})"]
    lines.append("")
    publish(lines, args.write, SECTION)
    return 0


if __name__ == "__main__":
    sys.exit(main())
