"""Builders shared by the storage tests (and the writer subprocess): Hamming-1 rounds."""

from __future__ import annotations

from storage import CandidateRecord, JobStatus, JobStore, RoundRecord

N_POSITIONS = 5
INITIAL = "0" * N_POSITIONS
T0 = 1_700_000_000.0


def flip(state: str, position: int) -> str:
    return state[:position] + ("1" if state[position] == "0" else "0") + state[position + 1:]


def hamming_round(index: int, parent: str, winner_position: int | None, *,
                  extra: dict | None = None) -> RoundRecord:
    """Round ``index`` around ``parent``: stay + one flip per position; the flip of
    ``winner_position`` wins (None: stay wins). Losses are distinct and deterministic."""
    states = [parent] + [flip(parent, p) for p in range(len(parent))]
    winner = parent if winner_position is None else flip(parent, winner_position)
    candidates = [
        CandidateRecord(state=s, train_loss=0.5 + k / 100, val_loss=(0.1 if s == winner else 0.6 + k / 100),
                        epochs=3, wall_s=1.25 + k, node=f"node-{k % 2}", seed=1000 * index + k,
                        extra={"epoch_losses": [0.9, 0.7, 0.5 + k / 100]})
        for k, s in enumerate(states)
    ]
    return RoundRecord(index=index, parent_state=parent, winner_state=winner,
                       candidates=tuple(candidates), started_at=T0 + 10 * index,
                       finished_at=T0 + 10 * index + 9, artifact_key=f"jobs/x/rounds/{index:04d}/ckpt",
                       extra=extra or {"pruned": [], "radius": 1})


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
