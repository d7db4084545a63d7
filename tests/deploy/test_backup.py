"""docs/DEPLOY.md's online backup of the job store, run as written (the container path mapped to a
directory): the copy, taken while the store is open and written to, holds every committed round."""

import re
import subprocess
import sys

from serve_process import REPO
from neuenh_service.storage import CandidateRecord, JobStatus, RoundRecord, SQLiteJobStore


def commit_rounds(store, job_id: str, n: int) -> list[RoundRecord]:
    state, done = "00", []
    for i in range(n):
        winner = f"{i % 2}{(i + 1) % 2}"
        candidates = tuple(CandidateRecord(state=s, train_loss=0.5, val_loss=0.1 if s == winner else 0.2,
                                           epochs=1, wall_s=1.0, node="n", seed=i)
                           for s in dict.fromkeys([state, winner]))
        done.append(store.commit_round(job_id, RoundRecord(i, state, winner, candidates, 0.0, 1.0,
                                                           f"jobs/{job_id}/rounds/{i:04d}/c")))
        state = winner
    return done


def test_the_documented_online_backup_copies_every_committed_round(tmp_path):
    doc = (REPO / "docs" / "DEPLOY.md").read_text()
    [code] = re.findall(r'docker compose exec api python -c "(.+)"', doc)
    store = SQLiteJobStore(tmp_path / "jobs.sqlite")  # the service holds it open (WAL)
    job = store.create_job({"model": "ggx"})[0].id
    store.set_status(job, JobStatus.PREPARING)
    store.set_status(job, JobStatus.RUNNING)
    rounds = commit_rounds(store, job, 3)
    subprocess.run([sys.executable, "-c", code.replace("/var/lib/neuenh", str(tmp_path))], check=True)
    copy = SQLiteJobStore(tmp_path / "backup.sqlite")
    try:
        assert copy.rounds(job) == rounds
        assert copy.get_job(job) == store.get_job(job)
    finally:
        copy.close()
        store.close()
