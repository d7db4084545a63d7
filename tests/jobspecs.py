"""Small job specs for fast orchestrator tests, and the reference a shared, crashed or distributed
run of one must equal: the spec run alone, in this process."""

from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import torch

from neuenh_service.orchestrator.runner import Orchestrator
from neuenh_service.orchestrator.spec import parse_spec
from neuenh_service.storage import LocalArtifactStore, SQLiteJobStore
from neuenh_service.workers.inline import InlineExecutor


def tiny_spec(**search):
    return parse_spec({
        "search": {"epochs_per_round": 1, "max_rounds": 3, **search},
        "train": {"batch_size": 1000, "lr": 5e-3},
        "data": [{"source": "synthetic_zoo", "materials": 2, "samples": 300, "seed": 1}],
    })


def fit_scored_spec(**search):
    """tiny_spec's search on 4 zoo materials, 2 of them held out: candidates are scored by fitting
    those (search.score: fit) with a small budget."""
    return parse_spec({
        "search": {"epochs_per_round": 1, "max_rounds": 2, "score": "fit",
                   "fit_score": {"fit_samples": 150, "test_samples": 150, "epochs": 8}, **search},
        "train": {"batch_size": 1000, "lr": 5e-3},
        "data": [{"source": "synthetic_zoo", "materials": 4, "samples": 300, "seed": 1, "holdout": 2}],
    })


def run_alone(where: Path, spec: dict) -> list[tuple]:
    """The spec's rounds (parent, winner, every candidate's state and validation loss) when run
    alone in this process with one thread per candidate, as a Ray task with one CPU trains it."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        with SQLiteJobStore(where / "alone.sqlite") as jobs:
            o = Orchestrator(jobs, LocalArtifactStore(where / "alone"), InlineExecutor())
            job = o.run(o.submit(parse_spec(spec))[0].id)
            return [(r.parent_state, r.winner_state, tuple((c.state, c.val_loss) for c in r.candidates))
                    for r in jobs.rounds(job.id)]
    finally:
        torch.set_num_threads(threads)


def run_alone_soon(where: Path, specs: list[dict]) -> Future:
    """``run_alone`` of each spec in turn, in a thread of this process started now; the future's
    result is their list. A test that then waits on a service training in its own processes gets
    its reference meanwhile instead of after (the two still share the machine's cores)."""
    pool = ThreadPoolExecutor(1, thread_name_prefix="run-alone")
    try:
        return pool.submit(lambda: [run_alone(where, spec) for spec in specs])
    finally:
        pool.shutdown(wait=False)


def served_path(history: dict) -> list[tuple]:
    """``run_alone``'s tuples from a served history (``GET /v1/jobs/{id}/history``)."""
    return [(r["parent_state"], r["winner_state"], tuple((c["state"], c["val_loss"]) for c in r["candidates"]))
            for r in history["rounds"]]
