"""Builders shared by the storage tests (and the writer subprocess): Hamming-1 rounds, and a
writer process killed mid-write."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

from neuenh_service.storage import CandidateRecord, JobStatus, JobStore, RoundRecord

N_POSITIONS = 5
INITIAL = "0" * N_POSITIONS
T0 = 1_700_000_000.0


def flip(state: str, position: int) -> str:
    return state[:position] + ("1" if state[position] == "0" else "0") + state[position + 1:]


def hamming_round(index: int, parent: str, winner_position: int | None, *,
                  extra: dict | None = None) -> RoundRecord:
    """Round ``index`` around ``parent``: stay + one flip per position; the flip of
    ``winner_position`` wins (None: stay wins). Losses are distinct and deterministic; every third
    candidate has no fit score."""
    states = [parent] + [flip(parent, p) for p in range(len(parent))]
    winner = parent if winner_position is None else flip(parent, winner_position)
    candidates = [
        CandidateRecord(state=s, train_loss=0.5 + k / 100, val_loss=(0.1 if s == winner else 0.6 + k / 100),
                        epochs=3, wall_s=1.25 + k, node=f"node-{k % 2}", seed=1000 * index + k,
                        extra={"epoch_losses": [0.9, 0.7, 0.5 + k / 100]},
                        fit_score=None if k % 3 == 2 else 0.2 + k / 100)  # some not scored
        for k, s in enumerate(states)
    ]
    return RoundRecord(index=index, parent_state=parent, winner_state=winner,
                       candidates=tuple(candidates), started_at=T0 + 10 * index,
                       finished_at=T0 + 10 * index + 9, artifact_key=f"jobs/x/rounds/{index:04d}/ckpt",
                       extra=extra or {"radius": 1})


def running_job(store: JobStore, spec: dict | None = None) -> str:
    job, _ = store.create_job(spec or {"model": "ggx"})
    store.set_status(job.id, JobStatus.PREPARING)
    store.set_status(job.id, JobStatus.RUNNING)
    return job.id


def commit_rounds(store: JobStore, job_id: str, n: int) -> list[RoundRecord]:
    """Commit rounds 0..n-1 (winner of round i flips position i % N_POSITIONS)."""
    state, done = INITIAL, []
    for i in range(n):
        record = hamming_round(i, state, i % N_POSITIONS)
        done.append(store.commit_round(job_id, record))
        state = record.winner_state
    return done


REPO = Path(__file__).resolve().parents[2]
VERSIONS = (b"A" * (8 << 20), b"B" * (8 << 20))  # what the writer alternates under WRITTEN_KEY
WRITTEN_KEY = "k/checkpoint"
WRITER = textwrap.dedent(f"""
    import sys
    from neuenh_service.storage import *
    store = eval(sys.argv[1])
    old, new = {VERSIONS[0][:1]!r} * (8 << 20), {VERSIONS[1][:1]!r} * (8 << 20)
    store.put({WRITTEN_KEY!r}, old)
    print("ready", flush=True)
    i = 0
    while True:
        store.put({WRITTEN_KEY!r}, new if i % 2 == 0 else old)
        i += 1
""")


def kill_a_writer_mid_write(opener: str, delay_s: float) -> None:
    """Start a process that opens an artifact store with the expression ``opener`` (names from
    ``storage``, e.g. ``"LocalArtifactStore('/tmp/x')"``) and rewrites ``WRITTEN_KEY`` with the
    two ``VERSIONS`` for ever; SIGKILL it ``delay_s`` after its first write (mid-write)."""
    writer = subprocess.Popen([sys.executable, "-c", WRITER, opener], cwd=REPO, stdout=subprocess.PIPE,
                              text=True)
    try:
        assert writer.stdout.readline().strip() == "ready"
        time.sleep(delay_s)  # the writer is somewhere in its put loop
        os.kill(writer.pid, signal.SIGKILL)
    finally:
        writer.kill()
        writer.wait()
        writer.stdout.close()
