"""``neuenh search SPEC.yaml``: run a search job in this process on embedded Ray.

    neuenh search examples/quickstart.yaml [--data-dir DIR] [--out DIR] [--json]

The job is stored in ``DATA_DIR/jobs.sqlite`` (artifacts in ``DATA_DIR/artifacts``) under a key
derived from the spec's content, so running the same spec again resumes an interrupted job from
its last committed round (or reports a finished one; ``--new`` starts afresh). At the end the
final bundle and the search history are written to ``--out`` (default ``DATA_DIR/results/<job>``),
and the plain analytical model (the spec's, GGX by default) is trained for the same total number of
epochs so the gain is measured, not assumed.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import time
from pathlib import Path

from neuenh.files import atomic_write
from neuenh_service.storage import JobStatus, LocalArtifactStore, OwnerLock, SQLiteJobStore, trained_epochs

from .outputs import output_folder
from .progress import ProgressDisplay
from .tables import against_plain, still_learning

SUCCESS = {JobStatus.CONVERGED, JobStatus.STOPPED}


def configure(p: argparse.ArgumentParser) -> None:
    """``neuenh search``'s arguments, on the parser ``cli.main`` made for it (with its one-line help)."""
    p.description = __doc__
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("spec", type=Path, metavar="SPEC.yaml")
    p.add_argument("--data-dir", type=Path, default=Path(os.environ.get("NEUENH_DATA_DIR", "neuenh-data")),
                   help="job store and artifacts (default: $NEUENH_DATA_DIR or ./neuenh-data)")
    p.add_argument("--out", type=Path, help="where to write the final bundle and history.json")
    p.add_argument("--cpus", type=int, default=None, help="CPUs of the embedded Ray (default: all)")
    p.add_argument("--ray-address", default=os.environ.get("RAY_ADDRESS"),
                   help="join an existing Ray cluster instead of starting one ($RAY_ADDRESS)")
    p.add_argument("--new", action="store_true", help="start a new job even if this spec ran before")
    p.add_argument("--no-baseline", action="store_true",
                   help="skip training the plain analytical model for the same epochs at the end")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(run=run)


def run(args) -> int:
    # The job's modules here and below, not at the top: they import torch (~1.5 s), which
    # `neuenh search --help` and a usage error need not pay.
    from neuenh_service.orchestrator.spec import load_spec

    spec = load_spec(args.spec)
    for flag, folder in (("--data-dir", args.data_dir), ("--out", args.out)):
        if folder is not None:
            output_folder(folder, flag)
    args.data_dir.mkdir(parents=True, exist_ok=True)
    with OwnerLock(args.data_dir / "owner.lock", owner="neuenh search"):  # not while a server runs its jobs
        return _search(spec, args)


def _search(spec, args) -> int:
    jobs = SQLiteJobStore(args.data_dir / "jobs.sqlite")
    artifacts = LocalArtifactStore(args.data_dir / "artifacts")
    # The key leaves out fields at their defaults, so a neuenh that adds spec fields (with defaults)
    # still finds the jobs of an earlier one; a job stored under another key whose spec reads as this
    # very spec today (an earlier neuenh's key) is found too.
    key = "spec-" + hashlib.sha256(json.dumps(spec.model_dump(mode="json", exclude_defaults=True),
                                              sort_keys=True).encode()).hexdigest()[:32]
    if args.new:
        key += f"-{time.time_ns()}"
    earlier = None if args.new else same_spec_job(jobs, spec)
    from neuenh_service.orchestrator.runner import Orchestrator
    from neuenh_service.workers.ray_executor import RayExecutor  # Ray only when a job really runs

    display = ProgressDisplay(sys.stderr)
    executor = RayExecutor(address=args.ray_address, num_cpus=args.cpus)
    try:
        orchestrator = Orchestrator(jobs, artifacts, executor, on_progress=display)
        job, created = (earlier, False) if earlier is not None else orchestrator.submit(spec, idempotency_key=key)
        display.note(f"job {job.id} {'submitted' if created else 'found: ' + job.status.lower()}"
                     f" ({args.data_dir / 'jobs.sqlite'})")
        job = orchestrator.run(job.id)
        display.done()
        summary = summarise(job, jobs, artifacts, spec, args, baseline=not args.no_baseline)
    finally:
        executor.close()
        jobs.close()
    print(json.dumps(summary, indent=2) if args.json else format_summary(summary))
    return 0 if job.status in SUCCESS else 1


def same_spec_job(jobs, spec):
    """The newest job of the store (not cancelled) whose stored spec is ``spec`` as this neuenh reads it."""
    from neuenh_service.orchestrator.spec import SpecError, parse_spec

    wanted = spec.model_dump(mode="json")
    for job in jobs.list_jobs(limit=500).jobs:
        if job.status is JobStatus.CANCELLED:
            continue
        try:
            if parse_spec(job.spec).model_dump(mode="json") == wanted:
                return job
        except SpecError:
            continue
    return None


def summarise(job, jobs, artifacts, spec, args, baseline: bool) -> dict:
    from neuenh.checkpoint import Bundle
    from neuenh_service.orchestrator.dataset import prepare_dataset
    from neuenh_service.orchestrator.runner import train_plain_baseline

    rounds = jobs.rounds(job.id)
    summary: dict = {"job": job.id, "status": job.status.value, "reason": job.reason, "error": job.error,
                     "rounds": len(rounds), "model": spec.model}
    if not rounds:
        return summary
    out = args.out or args.data_dir / "results" / job.id
    out.mkdir(parents=True, exist_ok=True)
    bundle = Bundle.from_bytes(artifacts.get(rounds[-1].artifact_key))
    bundle.provenance.update({"job": job.id, "spec": spec.model_dump(mode="json")})
    bundle.save(out / "model")
    from neuenh_service.api.schemas import HistoryPublic  # the file holds what GET /v1/jobs/{id}/history serves

    history = {"spec": spec.model_dump(mode="json"),
               **HistoryPublic.from_records(job, rounds).model_dump(mode="json")}
    atomic_write(out / "history.json", json.dumps(history, indent=2) + "\n")
    final = rounds[-1].winner
    stay0 = next(c for c in rounds[0].candidates if c.state == rounds[0].parent_state)
    summary.update({
        "state": final.state,
        "formula": bundle.model.describe(),
        "weights": bundle.model.n_weights(),
        "val_loss": final.val_loss,
        "fit_score": final.fit_score,
        "path": [r.winner_state for r in rounds],
        "round0_plain_val_loss": stay0.val_loss,
        "bundle": str(out / "model"),
        "history": str(out / "history.json"),
    })
    if baseline:
        epochs = trained_epochs(rounds)
        plain = train_plain_baseline(spec, prepare_dataset(spec, artifacts)[0], epochs)
        summary["plain_val_loss_same_epochs"] = plain.val_loss
        summary["plain_epochs"] = epochs
        summary["plain_epoch_losses"] = plain.epoch_losses
        summary["improvement"] = 1.0 - final.val_loss / plain.val_loss
    return summary


def format_summary(s: dict) -> str:
    reason = f" ({s['reason']})" if s.get("reason") else ""
    lines = [f"job {s['job']}: {s['status']}{reason} after {s['rounds']} round(s)"]
    if s.get("error"):
        lines.append(f"  error: {s['error']}")
    if "state" in s:
        lines += [
            f"  final state   {s['state']}  {s['formula']}  ({s['weights']} weights)",
            f"  path          {' -> '.join(s['path'])}",
            f"  val log-L1    {s['val_loss']:.5f} (plain {s['model']} after round 0: {s['round0_plain_val_loss']:.5f})",
        ]
        if s.get("fit_score") is not None:
            lines.append(f"  fit score     {s['fit_score']:.5f} (log-L1 on the held-out materials, fitted with the modules frozen)")
        if "plain_val_loss_same_epochs" in s:
            plain = s["plain_val_loss_same_epochs"]
            words = against_plain(s["val_loss"], plain, s["state"], f"plain {s['model']}")
            lines.append(f"  plain {s['model']} trained the same {s['plain_epochs']} epochs: {plain:.5f}  -> {words}")
            caveat = still_learning(f"plain {s['model']}", s["plain_epoch_losses"])
            if caveat:
                lines.append(f"  {'':14s}{caveat}")
        lines += [f"  bundle        {s['bundle']}", f"  history       {s['history']}"]
    return "\n".join(lines)
