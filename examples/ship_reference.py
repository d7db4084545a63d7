"""Ship a reference search's result as a model of ``models/`` (issues 6 and 14).

    .venv/bin/python examples/ship_reference.py runs/reference [--to models/enhanced-ggx]
    .venv/bin/python examples/ship_reference.py runs/reference-ward --spec examples/reference-ward.yaml \
        --to models/enhanced-ward
    .venv/bin/python examples/ship_reference.py runs/reference-fit --spec examples/reference-fit.yaml

Takes the finished job of the spec (default ``examples/reference.yaml``) from the store in that data
folder, and writes its final bundle (the winner of the last committed round: module weights, the
training materials' parameters) with its rungs (every committed round's winner, the latest round of
each state: the cheaper models on the way, ``neuenh.pretrained.rungs``) and the search written into its provenance — every round's candidates with
their validation loss, epochs and neural weights, the path, and the epoch budget
(``orchestrator.baselines.search_budget``) that ``neuenh report --train-baselines`` gives the
baselines. ``neuenh report`` draws the search from there.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from neuenh.checkpoint import Bundle, Rung  # noqa: E402
from neuenh_service.orchestrator.baselines import search_budget  # noqa: E402
from neuenh_service.orchestrator.spec import load_spec, neural_weights, parse_spec  # noqa: E402
from neuenh_service.storage import JobStatus, LocalArtifactStore, RoundKind, SQLiteJobStore  # noqa: E402



def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("data_dir", type=Path)
    parser.add_argument("--spec", type=Path, default=ROOT / "examples" / "reference.yaml")
    parser.add_argument("--to", type=Path, default=ROOT / "models" / "enhanced-ggx")
    args = parser.parse_args()
    spec_name = load_spec(args.spec).name
    jobs = SQLiteJobStore(args.data_dir / "jobs.sqlite")
    artifacts = LocalArtifactStore(args.data_dir / "artifacts")
    finished = jobs.list_jobs(status=(JobStatus.CONVERGED, JobStatus.STOPPED), limit=1000).jobs
    done = [j for j in finished if j.spec.get("name") == spec_name]
    if not done:
        sys.exit(f"{args.data_dir}: no finished {spec_name} job")
    job = done[0]  # newest first
    spec = parse_spec(job.spec)
    rounds = jobs.rounds(job.id)
    bundle = Bundle.from_bytes(artifacts.get(rounds[-1].artifact_key))
    latest = {r.winner_state: r for r in rounds}  # the latest committed round of each winning state
    bundle.rungs = [Rung.of(r.index, r.winner_val_loss, Bundle.from_bytes(artifacts.get(r.artifact_key)))
                    for r in sorted(latest.values(), key=lambda r: r.index)]
    budget = search_budget(spec, rounds)
    searched = [r for r in rounds if r.kind is RoundKind.SEARCH]
    warmup = rounds[0].warmup
    train_s = sum(r.finished_at - r.started_at for r in rounds) + (warmup.wall_s if warmup else 0.0)
    path = " → ".join([rounds[0].parent_state] + [r.winner_state for r in rounds if r.winner_state != r.parent_state])
    bundle.provenance = {
        **bundle.provenance,
        "search": {
            "spec": str(args.spec.resolve().relative_to(ROOT)), "job": job.id, "status": job.status.value, "budget": list(budget),
            "summary": (f"{len(searched)} rounds ({job.status.value.lower()})"
                        + (", then the polish" if len(searched) < len(rounds) else "")
                        + f", path {path}, {sum(budget)} epochs in all "
                        f"(warm-up {budget[0]}, rounds {budget[1]}, polish {budget[2]}), "
                        f"{train_s / 60:.0f} min on 2 cores"),
            "train_s": round(train_s, 1),
            "rounds": [{"index": r.index, "parent_state": r.parent_state, "winner_state": r.winner_state,
                        "kind": r.kind.value,
                        "warmup": dataclasses.asdict(r.warmup) if r.warmup else None,
                        "candidates": [{"state": c.state, "val_loss": c.val_loss, "fit_score": c.fit_score,
                                        "epochs": c.epochs, "weights": neural_weights(spec, c.state),
                                        "wall_s": round(c.wall_s, 1)}
                                       for c in r.candidates]}
                       for r in rounds],
        },
    }
    bundle.save(args.to)
    size = sum(p.stat().st_size for p in args.to.iterdir())
    print(f"{len(bundle.rungs)} rungs: " + ", ".join(f"{r.state} ({r.val_loss:.5f})" for r in bundle.rungs))
    print(f"shipped {bundle.model.describe()} (state {bundle.model.state}, {bundle.model.n_weights()} weights, "
          f"val log-L1 {rounds[-1].winner_val_loss:.5f}) to {args.to}, {size / 1024:.0f} KB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
