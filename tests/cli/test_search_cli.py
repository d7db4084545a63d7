"""``neuenh search`` as a user runs it, on embedded Ray: killed with SIGKILL mid-round and started
again, it finishes with the same states and losses as an uninterrupted run, and no committed
round is lost."""

import json
import os
import signal
import subprocess
import sys
import time

import pytest
import yaml

from neuenh_service.storage import SQLiteJobStore

from jobspecs import run_alone

SPEC = {
    "search": {"epochs_per_round": 3, "max_rounds": 3},
    "train": {"batch_size": 1000, "lr": 5e-3},
    "data": [{"source": "synthetic_zoo", "materials": 3, "samples": 1200, "seed": 1}],
}


def search(spec, data_dir, *extra, wait=True):
    cmd = [sys.executable, "-m", "neuenh_service.cli.main", "search", str(spec), "--data-dir", str(data_dir), "--cpus", "2",
           "--no-baseline", "--json", *extra]
    if not wait:
        return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    return subprocess.run(cmd, capture_output=True, text=True, timeout=300)


def history(data_dir):
    with SQLiteJobStore(data_dir / "jobs.sqlite") as jobs:
        (job,) = jobs.list_jobs().jobs
        return job, [(r.index, r.winner_state, r.winner_val_loss, sorted((c.state, c.val_loss) for c in r.candidates))
                     for r in jobs.rounds(job.id)]


@pytest.fixture(scope="module")
def spec_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("spec") / "job.yaml"
    path.write_text(yaml.safe_dump(SPEC))
    return path


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    """What a run that is never killed commits, in ``history``'s form: computed in this process
    (``run_alone``: what a Ray task of one CPU computes, as tests/api/test_shared_cluster.py checks
    against the served search), not by a second ``neuenh search`` with its own Ray."""
    rounds = run_alone(tmp_path_factory.mktemp("ref"), SPEC)
    return [(i, winner, dict(candidates)[winner], sorted(candidates))
            for i, (_, winner, candidates) in enumerate(rounds)]


def _wait_for_round_1_in_progress(data_dir, proc, timeout=180):
    deadline = time.time() + timeout
    while time.time() < deadline:
        assert proc.poll() is None, proc.stderr.read().decode()
        if (data_dir / "jobs.sqlite").exists():
            with SQLiteJobStore(data_dir / "jobs.sqlite") as jobs:
                page = jobs.list_jobs().jobs
                if page and page[0].last_round == 0:
                    done = [e for e in jobs.events(page[0].id) if e.kind == "candidate" and e.payload["round"] == 1]
                    if len(done) >= 2:
                        return
        time.sleep(0.05)
    raise AssertionError("round 1 never started")


def test_sigkill_mid_round_then_resume(spec_file, uninterrupted, tmp_path):
    expected = uninterrupted
    proc = search(spec_file, tmp_path, wait=False)
    _wait_for_round_1_in_progress(tmp_path, proc)
    os.killpg(proc.pid, signal.SIGKILL)  # the orchestrator and its embedded Ray, without warning
    proc.wait(timeout=30)
    job, committed = history(tmp_path)
    assert job.status == "RUNNING" and [r[0] for r in committed] == [0]
    assert committed[0] == expected[0]

    again = search(spec_file, tmp_path)  # the same spec finds the same job and resumes it
    assert again.returncode == 0, again.stderr
    resumed = json.loads(again.stdout)
    assert resumed["job"] == job.id
    assert history(tmp_path)[1] == expected
    assert (resumed["state"], resumed["val_loss"]) == expected[-1][1:3]
    assert json.loads((tmp_path / "results" / job.id / "history.json").read_text())["rounds"][0]["round"] == 0


def test_a_job_stored_by_an_earlier_neuenh_is_found_by_its_spec(tmp_path):
    """A spec stored without fields an upgrade added (their defaults), under another key, is the
    same spec: neuenh search resumes that job instead of starting afresh; a cancelled one is not."""
    from neuenh_service.cli.search import same_spec_job
    from neuenh_service.orchestrator.spec import parse_spec
    from neuenh_service.storage import JobStatus, SQLiteJobStore

    spec = parse_spec({"search": {"epochs_per_round": 2}, "data": [{"source": "synthetic_zoo", "materials": 2}]})
    with SQLiteJobStore(tmp_path / "jobs.sqlite") as jobs:
        old_form = spec.model_dump(mode="json", exclude_defaults=True)  # what an earlier schema held
        cancelled, _ = jobs.create_job(old_form, idempotency_key="spec-old-1")
        jobs.set_status(cancelled.id, JobStatus.CANCELLED)
        assert same_spec_job(jobs, spec) is None
        kept, _ = jobs.create_job(old_form, idempotency_key="spec-old-2")
        jobs.create_job({**old_form, "latent_dim": 5}, idempotency_key="spec-other")
        assert same_spec_job(jobs, spec).id == kept.id


@pytest.mark.parametrize("state, val_loss, words", [
    ("00000010000", 0.03927, "-> the enhancement does not lower the validation loss: 15.3% above plain ggx's"),
    ("00000010000", 0.03000, "-> the enhancement lowers the validation loss by 11.9%"),
    ("00000000000", 0.03250, "-> the search kept plain ggx: no module paid on this data"),
], ids=["enhanced-above", "enhanced-below", "kept-plain"])
def test_the_summary_credits_an_enhancement_only_when_there_is_one(state, val_loss, words):
    """The fair baseline's line: a search that ended at its start state has no enhancement to credit."""
    from neuenh_service.cli.search import format_summary

    summary = {"job": "j", "status": "CONVERGED", "rounds": 1, "state": state, "formula": "M + S", "weights": 0,
               "path": [state], "val_loss": val_loss, "round0_plain_val_loss": 0.1, "model": "ggx",
               "plain_val_loss_same_epochs": 0.03405, "plain_epochs": 60, "plain_epoch_losses": [0.05] * 60,
               "bundle": "b", "history": "h"}
    (line,) = [ln for ln in format_summary(summary).splitlines() if "trained the same 60 epochs" in ln]
    assert words in line
    assert "at equal epochs only" not in format_summary(summary)  # a baseline that had levelled off


def test_the_summary_says_when_the_baseline_was_still_learning():
    """Plain GGX's training loss 1/(e + 1) over 32 epochs fell 1 - 24/32 = 25 % over the last 8: the
    comparison at equal epochs is said to hold at that budget only, on the line after it."""
    from neuenh_service.cli.search import format_summary

    summary = {"job": "j", "status": "STOPPED", "rounds": 3, "state": "00000010001", "formula": "M + S", "weights": 0,
               "path": ["00000010001"], "val_loss": 0.04816, "round0_plain_val_loss": 0.1, "model": "ggx",
               "plain_val_loss_same_epochs": 0.06082, "plain_epochs": 32,
               "plain_epoch_losses": [1 / (e + 1) for e in range(32)], "bundle": "b", "history": "h"}
    lines = format_summary(summary).splitlines()
    at = next(i for i, ln in enumerate(lines) if "trained the same 32 epochs" in ln)
    assert "the enhancement lowers the validation loss by 20.8%" in lines[at]
    assert lines[at + 1].strip() == "at equal epochs only: plain ggx's training loss still fell 25.0% over its last 8 epochs"
