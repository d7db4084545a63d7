"""Search benchmark (issue 4): what a round costs and how it scales, measured side by side.

    .venv/bin/python bench/bench_search.py --write docs/BENCHMARKS.md

1. Round wall time of one radius-1 round (12 candidates) on an embedded Ray with 1 and with 2
   CPUs (one candidate per CPU): parallel efficiency T1 / (2 T2).
2. The orchestrator's own overhead as a fraction of a round: the round's wall time minus the
   candidates' training time (summed, divided by the workers), with the in-process executor (pure
   orchestration: dataset, store commits, checkpoint serialisation) and with Ray (plus scheduling
   and object transfer).
3. Radius 1 vs 2 for one round from the analytical state: candidates, wall time, winner.
4. Successive halving on vs off for a whole job: wall time, rounds, the path and final state.

All jobs use the quickstart's data (examples/quickstart.yaml).
"""

from __future__ import annotations

import argparse
import datetime as dt
import sys
import tempfile
import time
from pathlib import Path

import ray
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from bench.harness import fitting_process  # noqa: E402
from bench.report import publish  # noqa: E402
from neuenh.data.sources import materialise  # noqa: E402
from neuenh_service.orchestrator.runner import Orchestrator, train_plain_baseline  # noqa: E402
from neuenh_service.orchestrator.spec import load_spec  # noqa: E402
from neuenh_service.storage import LocalArtifactStore, SQLiteJobStore  # noqa: E402
from neuenh_service.workers.inline import InlineExecutor  # noqa: E402
from neuenh_service.workers.ray_executor import RayExecutor  # noqa: E402

SECTION = "## Search rounds and scaling (issue 4)"


def quickstart(**search):
    spec = load_spec(ROOT / "examples" / "quickstart.yaml")
    return spec.model_copy(update={"search": spec.search.model_copy(update=search)})


def run_job(spec, executor, workdir: Path) -> dict:
    jobs = SQLiteJobStore(workdir / "jobs.sqlite")
    o = Orchestrator(jobs, LocalArtifactStore(workdir / "artifacts"), executor)
    start = time.perf_counter()
    job = o.run(o.submit(spec)[0].id)
    wall = time.perf_counter() - start
    rounds = jobs.rounds(job.id)
    jobs.close()
    return {"status": job.status.value, "wall_s": wall, "rounds": rounds,
            "path": [r.winner_state for r in rounds], "final": rounds[-1].winner_state,
            "val": rounds[-1].winner_val_loss}


def round_stats(result: dict, workers: int) -> dict:
    r = result["rounds"][0]
    wall = r.finished_at - r.started_at
    busy = sum(c.wall_s for c in r.candidates)
    return {"candidates": len(r.candidates), "wall_s": wall, "train_s": busy,
            "overhead": max(0.0, wall - busy / workers) / wall, "winner": r.winner_state,
            "val": r.winner_val_loss}


def with_ray(cpus: int, fn):
    if ray.is_initialized():
        ray.shutdown()
    executor = RayExecutor(num_cpus=cpus, object_store_memory=256 * 1024**2)
    try:
        return fn(executor)
    finally:
        executor.close()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--write", metavar="PATH", help="write/replace this section of PATH")
    args = parser.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="bench-search-"))
    one_round = quickstart(max_rounds=1)

    fitting_process()  # the in-process executor gets what one Ray worker gets
    inline = round_stats(run_job(one_round, InlineExecutor(), tmp / "inline"), 1)
    print("inline round", inline, flush=True)
    ray1 = with_ray(1, lambda ex: round_stats(run_job(one_round, ex, tmp / "ray1"), 1))
    print("ray 1 cpu", ray1, flush=True)
    ray2 = with_ray(2, lambda ex: round_stats(run_job(one_round, ex, tmp / "ray2"), 2))
    print("ray 2 cpus", ray2, flush=True)
    r2 = with_ray(2, lambda ex: round_stats(run_job(quickstart(max_rounds=1, radius=2), ex, tmp / "r2"), 2))
    print("radius 2", r2, flush=True)
    plain = with_ray(2, lambda ex: run_job(quickstart(), ex, tmp / "plain"))
    print("job, no pruning", plain["wall_s"], plain["path"], flush=True)
    spec = quickstart()
    data = materialise(spec.data, spec.train.val_fraction, spec.train.seed)
    baseline = train_plain_baseline(spec, data, sum(r.winner.epochs for r in plain["rounds"])).val_loss
    print("plain GGX, same epochs", baseline, flush=True)
    halving = with_ray(2, lambda ex: run_job(quickstart(prune="halving"), ex, tmp / "halving"))
    print("job, halving", halving["wall_s"], halving["path"], flush=True)

    efficiency = ray1["wall_s"] / (2 * ray2["wall_s"])
    date = dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    lines = [
        SECTION, "",
        "Command: `.venv/bin/python bench/bench_search.py --write docs/BENCHMARKS.md` "
        f"({date}; 2-core AMD EPYC, torch {torch.__version__}, Ray {ray.__version__}; one torch thread "
        "per candidate). Data: the quickstart's 20 synthetic materials × 2000 samples, 10 epochs a round.",
        "",
        "| one radius-1 round from the analytical state | candidates | round wall (s) | training, summed (s) | orchestration overhead | winner |",
        "|---|---|---|---|---|---|",
        f"| in-process executor, 1 thread | {inline['candidates']} | {inline['wall_s']:.1f} | {inline['train_s']:.1f} | {100 * inline['overhead']:.1f} % | `{inline['winner']}` |",
        f"| Ray, 1 CPU (1 worker) | {ray1['candidates']} | {ray1['wall_s']:.1f} | {ray1['train_s']:.1f} | {100 * ray1['overhead']:.1f} % | `{ray1['winner']}` |",
        f"| Ray, 2 CPUs (2 workers) | {ray2['candidates']} | {ray2['wall_s']:.1f} | {ray2['train_s']:.1f} | {100 * ray2['overhead']:.1f} % | `{ray2['winner']}` |",
        f"| Ray, 2 CPUs, **radius 2** | {r2['candidates']} | {r2['wall_s']:.1f} | {r2['train_s']:.1f} | {100 * r2['overhead']:.1f} % | `{r2['winner']}` |",
        "",
        f"- Parallel efficiency, 1 → 2 workers: T1 / (2·T2) = {ray1['wall_s']:.1f} / (2 × {ray2['wall_s']:.1f}) = **{efficiency:.2f}**.",
        "- Overhead = (round wall − summed training / workers) / round wall: for the in-process executor this is "
        "the orchestrator alone (dataset, candidate bundles, store commit); with Ray it adds scheduling, object "
        "transfer and, in the first round on a fresh cluster as here, starting the worker processes (each imports "
        "torch once); the 67-candidate round amortises that.",
        f"- Radius 2 trains {r2['candidates']} candidates instead of {ray2['candidates']}: "
        f"{r2['wall_s'] / ray2['wall_s']:.1f}× the wall time for a round, winner `{r2['winner']}` "
        f"(val {r2['val']:.5f}) vs `{ray2['winner']}` (val {ray2['val']:.5f}).",
        "",
        "| whole quickstart job, Ray 2 CPUs | status | wall (s) | rounds | path | final val log-L1 |",
        "|---|---|---|---|---|---|",
        f"| no pruning | {plain['status']} | {plain['wall_s']:.1f} | {len(plain['rounds'])} | {' → '.join(plain['path'])} | {plain['val']:.5f} |",
        f"| successive halving (1/3 of the epochs, keep the better half) | {halving['status']} | {halving['wall_s']:.1f} | {len(halving['rounds'])} | {' → '.join(halving['path'])} | {halving['val']:.5f} |",
        "",
        f"The quickstart's enhancement, measured: the search's final state `{plain['final']}` reaches "
        f"{plain['val']:.5f}; plain GGX trained for the same {sum(r.winner.epochs for r in plain['rounds'])} "
        f"epochs reaches {baseline:.5f}, so enhancement lowers the validation loss by "
        f"{100 * (1 - plain['val'] / baseline):.1f} % (what `make demo` prints at its end).",
        "",
        f"Halving took {halving['wall_s'] / plain['wall_s']:.2f}× the time of the full search; it chose "
        f"{'the same' if halving['path'] == plain['path'] else 'a different'} path "
        f"(final val {halving['val']:.5f} vs {plain['val']:.5f}): candidates judged after a third of the epochs "
        "can drop a module that would have won with the full budget.",
        "",
    ]
    publish(lines, args.write, SECTION)
    return 0


if __name__ == "__main__":
    sys.exit(main())
