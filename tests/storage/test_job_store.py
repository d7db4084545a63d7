"""The JobStore contract, run against every backend of ``conftest.JOB_BACKENDS``."""

from __future__ import annotations

import dataclasses
import itertools
import math
import threading
import time

import pytest
from storage_kit import INITIAL, N_POSITIONS, commit_rounds, flip, hamming_round, running_job

from neuenh_service.storage import (TRANSITIONS, UNFINISHED, CandidateRecord,
                     ConflictError, EventKind, FinishedCandidate, IllegalTransitionError, InvalidRecordError, JobStatus,
                     HalvingRecord, NotFoundError, RoundKind, RoundRecord, StorageError, WarmupRecord)

S = JobStatus

# A path from QUEUED to each status, through legal edges only.
PATH_TO = {
    S.QUEUED: [],
    S.PREPARING: [S.PREPARING],
    S.RUNNING: [S.PREPARING, S.RUNNING],
    S.CONVERGED: [S.PREPARING, S.RUNNING, S.CONVERGED],
    S.STOPPED: [S.PREPARING, S.RUNNING, S.STOPPED],
    S.CANCELLED: [S.CANCELLED],
    S.FAILED: [S.FAILED],
}
LEGAL = [(a, b) for a in S for b in sorted(TRANSITIONS[a])]
ILLEGAL = [(a, b) for a, b in itertools.product(S, S) if b not in TRANSITIONS[a]]


def job_in(store, status: JobStatus, spec=None) -> str:
    job, _ = store.create_job(spec or {"model": "ggx"})
    for step in PATH_TO[status]:
        store.set_status(job.id, step)
    return job.id


def test_state_machine_is_the_documented_one():
    """The moves ARCHITECTURE §3 describes, written out here (not derived from ``TRANSITIONS``): forward
    through preparation and training to an end, or cancelled/failed from any unfinished status."""
    documented = {(S.QUEUED, S.PREPARING), (S.PREPARING, S.RUNNING), (S.RUNNING, S.CONVERGED),
                  (S.RUNNING, S.STOPPED)} | {(a, b) for a in (S.QUEUED, S.PREPARING, S.RUNNING)
                                             for b in (S.CANCELLED, S.FAILED)}
    assert set(LEGAL) == documented and len(ILLEGAL) == len(S) ** 2 - len(documented)
    assert UNFINISHED == {S.QUEUED, S.PREPARING, S.RUNNING}
    assert all(s.terminal for s in (S.CONVERGED, S.STOPPED, S.CANCELLED, S.FAILED))


class TestJobStoreContract:
    # ------------------------------------------------------------------------------- jobs

    def test_create_and_get(self, job_store):
        spec = {"model": "ggx", "search": {"radius": 1, "max_neural": None}, "data": [{"samples": 20}]}
        before = time.time()
        job, created = job_store.create_job(spec)
        assert created and job.status is S.QUEUED and job.spec == spec
        assert before <= job.created_at == job.updated_at <= time.time()
        assert (job.last_round, job.current_state, job.error, job.next_round) == (None, None, None, 0)
        assert job_store.get_job(job.id) == job
        other, _ = job_store.create_job(spec)
        assert other.id != job.id

    @pytest.mark.parametrize("call", [
        lambda s: s.get_job("nope"),
        lambda s: s.set_status("nope", S.PREPARING),
        lambda s: s.commit_round("nope", hamming_round(0, INITIAL, 0)),
        lambda s: s.rounds("nope"),
        lambda s: s.last_round("nope"),
        lambda s: s.append_event("nope", "log"),
        lambda s: s.events("nope"),
    ], ids=["get", "set_status", "commit_round", "rounds", "last_round", "append_event", "events"])
    def test_unknown_job_is_not_found(self, job_store, call):
        with pytest.raises(NotFoundError, match="nope") as info:
            call(job_store)
        assert isinstance(info.value, KeyError)

    def test_idempotency_key_returns_the_existing_job(self, job_store):
        spec = {"model": "ggx", "search": {"radius": 2}}
        first, created = job_store.create_job(spec, idempotency_key="submit-1")
        again, created_again = job_store.create_job(dict(spec), idempotency_key="submit-1")
        assert created and not created_again and again == first
        other, created_other = job_store.create_job(spec, idempotency_key="submit-2")
        assert created_other and other.id != first.id
        assert len(job_store.list_jobs().jobs) == 2
        assert len(job_store.events(first.id)) == 1  # the repeat wrote nothing

    def test_idempotency_keys_are_per_owner(self, job_store):
        alices, _ = job_store.create_job({"model": "ggx"}, idempotency_key="k", owner="alice")
        bobs, created = job_store.create_job({"model": "ward"}, idempotency_key="k", owner="bob")
        assert created and bobs.id != alices.id and bobs.idempotency_key == "k"  # no 409 naming alice's job
        assert job_store.create_job({"model": "ggx"}, idempotency_key="k", owner="alice") == (alices, False)
        with pytest.raises(InvalidRecordError, match="line breaks"):
            job_store.create_job({"model": "ggx"}, idempotency_key="a\nk", owner=None)

    def test_idempotency_key_with_another_spec_conflicts(self, job_store):
        job_store.create_job({"model": "ggx"}, idempotency_key="k")
        with pytest.raises(ConflictError, match="idempotency key 'k'"):
            job_store.create_job({"model": "ward"}, idempotency_key="k")
        assert len(job_store.list_jobs().jobs) == 1

    def test_concurrent_submits_with_one_key_make_one_job(self, job_store):
        results = []

        def submit():
            results.append(job_store.create_job({"model": "ggx"}, idempotency_key="same"))

        threads = [threading.Thread(target=submit) for _ in range(6)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert len({job.id for job, _ in results}) == 1
        assert sum(created for _, created in results) == 1

    @pytest.mark.parametrize("spec", [{"lr": math.nan}, {"x": math.inf}, {"x": object()}, ["ggx"]],
                             ids=["nan", "inf", "object", "not-a-mapping"])
    def test_spec_must_be_a_strict_json_object(self, job_store, spec):
        with pytest.raises(InvalidRecordError):
            job_store.create_job(spec)
        assert job_store.list_jobs().jobs == ()

    def test_list_jobs_pages_newest_first(self, job_store):
        ids = [job_store.create_job({"n": i})[0].id for i in range(7)]
        page = job_store.list_jobs(limit=3)
        seen = [j.id for j in page.jobs]
        assert seen == ids[::-1][:3] and page.next_cursor is not None
        job_store.create_job({"n": "late"})  # a new job must not shift the following pages
        while page.next_cursor is not None:
            page = job_store.list_jobs(limit=3, cursor=page.next_cursor)
            seen += [j.id for j in page.jobs]
        assert seen == ids[::-1]
        exact = job_store.list_jobs(limit=8)
        assert len(exact.jobs) == 8 and exact.next_cursor is None

    def test_list_jobs_filters_by_status(self, job_store):
        by_status = {s: [job_in(job_store, s) for _ in range(2)] for s in S}
        for s in S:
            assert [j.id for j in job_store.list_jobs(status=s).jobs] == by_status[s][::-1]
        both = job_store.list_jobs(status=[S.RUNNING, S.FAILED], limit=3)
        rest = job_store.list_jobs(status=[S.RUNNING, S.FAILED], limit=3, cursor=both.next_cursor)
        assert {j.id for j in both.jobs + rest.jobs} == set(by_status[S.RUNNING] + by_status[S.FAILED])
        assert rest.next_cursor is None and len(rest.jobs) == 1
        assert job_store.list_jobs(status="QUEUED").jobs == job_store.list_jobs(status=S.QUEUED).jobs
        assert len(job_store.list_jobs(limit=100).jobs) == 14

    @pytest.mark.parametrize("kwargs", [{"limit": 0}, {"cursor": "not-a-cursor"}, {"status": "DONE"}])
    def test_list_jobs_rejects_bad_arguments(self, job_store, kwargs):
        with pytest.raises(InvalidRecordError):
            job_store.list_jobs(**kwargs)

    def test_unfinished_jobs_oldest_first(self, job_store):
        ids = {s: job_in(job_store, s) for s in S}
        unfinished = job_store.unfinished_jobs()
        assert [j.id for j in unfinished] == [ids[S.QUEUED], ids[S.PREPARING], ids[S.RUNNING]]

    def test_survives_reopening(self, job_backend):
        store = job_backend.open()
        job_id = running_job(store)
        committed = commit_rounds(store, job_id, 2)
        store.append_event(job_id, "log", {"msg": "hi"})
        job = store.get_job(job_id)
        store.close()
        reopened = job_backend.open()
        assert reopened.get_job(job_id) == job
        assert reopened.rounds(job_id) == committed
        assert reopened.events(job_id)[-1].payload == {"msg": "hi"}
        assert [j.id for j in reopened.unfinished_jobs()] == [job_id]

    def test_closed_store_refuses_calls(self, job_backend):
        store = job_backend.open()
        store.close()
        with pytest.raises(StorageError, match="closed"):
            store.list_jobs()

    # ----------------------------------------------------------------------------- status

    @pytest.mark.parametrize("old,new", LEGAL, ids=[f"{a}->{b}" for a, b in LEGAL])
    def test_legal_transition(self, job_store, old, new):
        job_id = job_in(job_store, old)
        before = job_store.get_job(job_id)
        error = "boom" if new is S.FAILED else None
        job = job_store.set_status(job_id, new, error=error)
        assert job.status is new and job.error == error and job.updated_at >= before.updated_at
        assert job_store.get_job(job_id) == job
        event = job_store.events(job_id)[-1]
        assert (event.kind, event.payload) == (EventKind.STATUS, {"status": new.value, "previous": old.value,
                                                              "error": error})

    @pytest.mark.parametrize("old,new", ILLEGAL, ids=[f"{a}->{b}" for a, b in ILLEGAL])
    def test_illegal_transition(self, job_store, old, new):
        job_id = job_in(job_store, old)
        before, n_events = job_store.get_job(job_id), len(job_store.events(job_id))
        with pytest.raises(IllegalTransitionError, match=f"from {old.value} to {new.value}"):
            job_store.set_status(job_id, new)
        assert job_store.get_job(job_id) == before
        assert len(job_store.events(job_id)) == n_events

    def test_error_reason_only_with_a_terminal_status(self, job_store):
        job_id = job_in(job_store, S.QUEUED)
        with pytest.raises(InvalidRecordError, match="terminal"):
            job_store.set_status(job_id, S.PREPARING, error="why")
        assert job_store.get_job(job_id).status is S.QUEUED
        job = job_store.set_status(job_id, S.CANCELLED, error="cancelled by alice")
        assert job.error == "cancelled by alice"
        with pytest.raises(InvalidRecordError, match="unknown job status"):
            job_store.set_status(job_in(job_store, S.QUEUED), "DONE")

    def test_creation_and_every_change_are_events(self, job_store):
        job_id = job_in(job_store, S.CONVERGED)
        events = job_store.events(job_id)
        assert [e.seq for e in events] == [1, 2, 3, 4]
        assert [(e.payload["previous"], e.payload["status"]) for e in events] == [
            (None, "QUEUED"), ("QUEUED", "PREPARING"), ("PREPARING", "RUNNING"), ("RUNNING", "CONVERGED")]

    def test_racing_terminal_changes_have_one_winner(self, job_store):
        for _ in range(5):
            job_id = running_job(job_store)
            outcomes = {}

            def change(status):
                try:
                    job_store.set_status(job_id, status)
                    outcomes[status] = "won"
                except IllegalTransitionError:
                    outcomes[status] = "lost"

            threads = [threading.Thread(target=change, args=(s,)) for s in (S.CANCELLED, S.CONVERGED)]
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            assert sorted(outcomes.values()) == ["lost", "won"]
            winner = next(s for s, o in outcomes.items() if o == "won")
            assert job_store.get_job(job_id).status is winner

    # ----------------------------------------------------------------------------- rounds

    def test_commit_round_makes_it_visible_whole(self, job_store):
        job_id = running_job(job_store)
        assert job_store.last_round(job_id) is None and job_store.rounds(job_id) == []
        record = hamming_round(0, INITIAL, 3)
        stored = job_store.commit_round(job_id, record)
        assert stored == record
        assert job_store.rounds(job_id) == [record]
        assert job_store.last_round(job_id) == record
        states = [c.state for c in job_store.last_round(job_id).candidates]
        assert states == [c.state for c in record.candidates]
        job = job_store.get_job(job_id)
        assert (job.last_round, job.current_state, job.next_round) == (0, flip(INITIAL, 3), 1)
        event = job_store.events(job_id)[-1]
        assert event.kind == EventKind.ROUND
        assert event.payload == {"round": 0, "winner_state": flip(INITIAL, 3), "winner_val_loss": 0.1,
                                 "winner_fit_score": record.winner_fit_score, "artifact_key": record.artifact_key}

    def test_failed_commit_leaves_nothing_of_the_round(self, job_store):
        job_id = running_job(job_store)
        commit_rounds(job_store, job_id, 1)
        job, events = job_store.get_job(job_id), job_store.events(job_id)
        good = hamming_round(1, job.current_state, 0)
        # The last candidate repeats a state: the round row and the first candidates are already
        # inserted when the schema rejects it inside the transaction.
        bad = dataclasses.replace(good, candidates=good.candidates + (
            dataclasses.replace(good.candidates[1], seed=7),))
        with pytest.raises(InvalidRecordError, match="nothing was written"):
            job_store.commit_round(job_id, bad)
        assert len(job_store.rounds(job_id)) == 1
        assert job_store.rounds(job_id, since_round=1) == []
        assert job_store.last_round(job_id).index == 0
        assert job_store.get_job(job_id) == job
        assert job_store.events(job_id) == events
        assert job_store.commit_round(job_id, good) == good  # the round can be committed afterwards
        assert [r.index for r in job_store.rounds(job_id)] == [0, 1]

    def test_recommit_is_idempotent_by_content(self, job_store):
        job_id = running_job(job_store)
        record = commit_rounds(job_store, job_id, 2)[0]
        n_events, job = len(job_store.events(job_id)), job_store.get_job(job_id)
        assert job_store.commit_round(job_id, hamming_round(0, INITIAL, 0)) == record
        assert len(job_store.events(job_id)) == n_events and job_store.get_job(job_id) == job
        changed = dataclasses.replace(record, finished_at=record.finished_at + 1)
        with pytest.raises(ConflictError, match="round 0 is already committed with different content"):
            job_store.commit_round(job_id, changed)
        job_store.set_status(job_id, S.CONVERGED)
        assert job_store.commit_round(job_id, record) == record  # a retry after the job finished

    def test_rounds_commit_in_order_from_the_current_state(self, job_store):
        job_id = running_job(job_store)
        with pytest.raises(ConflictError, match="next round to commit is 0, not 1"):
            job_store.commit_round(job_id, hamming_round(1, INITIAL, 0))
        commit_rounds(job_store, job_id, 1)
        with pytest.raises(ConflictError, match="starts from"):
            job_store.commit_round(job_id, hamming_round(1, INITIAL, 1))
        assert [r.index for r in job_store.rounds(job_id)] == [0]

    @pytest.mark.parametrize("status", [s for s in S if s is not S.RUNNING])
    def test_rounds_commit_only_while_running(self, job_store, status):
        job_id = job_in(job_store, status)
        with pytest.raises(ConflictError, match=f"is {status.value}"):
            job_store.commit_round(job_id, hamming_round(0, INITIAL, 0))
        assert job_store.rounds(job_id) == [] and job_store.get_job(job_id).last_round is None

    def test_non_finite_losses_are_stored_as_none(self, job_store):
        job_id = running_job(job_store)
        base = hamming_round(0, INITIAL, 0)
        diverged = dataclasses.replace(base.candidates[2], train_loss=math.inf, val_loss=math.nan,
                                       error="non-finite loss")
        candidates = base.candidates[:2] + (diverged,) + base.candidates[3:]
        record = dataclasses.replace(base, candidates=candidates)
        job_store.commit_round(job_id, record)
        stored = job_store.last_round(job_id).candidates[2]
        assert (stored.train_loss, stored.val_loss, stored.ok) == (None, None, False)
        assert stored.error == "non-finite loss"

    def test_typed_round_fields_round_trip(self, job_store):
        """A warmed-up, halved round 0 and a polish round come back as they were committed."""
        job_id = running_job(job_store)
        base = hamming_round(0, INITIAL, 1)
        pruned = dataclasses.replace(base.candidates[3], pruned=True, error="pruned by successive halving")
        first = dataclasses.replace(
            base, candidates=base.candidates[:3] + (pruned,) + base.candidates[4:],
            warmup=WarmupRecord(epochs=5, train_loss=0.4, val_loss=math.nan, wall_s=2.0, node="n"),
            halving=HalvingRecord(first_epochs=1, early_val_loss={c.state: 0.5 for c in base.candidates}))
        job_store.commit_round(job_id, first)
        second = dataclasses.replace(hamming_round(1, first.winner_state, 2), stop_reason="gain 0.5 % < 1 %")
        job_store.commit_round(job_id, second)
        polish = dataclasses.replace(hamming_round(2, second.winner_state, None), kind=RoundKind.POLISH,
                                     outcome=S.STOPPED)
        job_store.commit_round(job_id, polish)
        assert job_store.rounds(job_id) == [first, second, polish]
        assert [r.stop_reason for r in job_store.rounds(job_id)] == [None, "gain 0.5 % < 1 %", None]
        stored = job_store.rounds(job_id)[0]
        assert stored.warmup.val_loss is None and stored.candidates[3].pruned and not stored.candidates[2].pruned
        assert job_store.last_round(job_id).outcome is S.STOPPED

    def test_history_since_round(self, job_store):
        job_id = running_job(job_store)
        committed = commit_rounds(job_store, job_id, 6)
        other = running_job(job_store)
        commit_rounds(job_store, other, 2)
        assert job_store.rounds(job_id) == committed
        assert job_store.rounds(job_id, since_round=4) == committed[4:]
        assert job_store.rounds(job_id, since_round=6) == []
        assert job_store.rounds(job_id, until_round=0) == committed[:1]
        assert job_store.rounds(job_id, since_round=2, until_round=3) == committed[2:4]
        assert [r.index for r in job_store.rounds(other)] == [0, 1]
        chain = job_store.rounds(job_id)
        assert all(a.winner_state == b.parent_state for a, b in zip(chain, chain[1:]))
        r = chain[5]
        assert r.extra == {"radius": 1} and r.candidates[1].extra["epoch_losses"][0] == 0.9
        assert [c.seed for c in r.candidates] == [5000 + k for k in range(N_POSITIONS + 1)]
        assert [c.fit_score for c in r.candidates] == [None if k % 3 == 2 else 0.2 + k / 100 for k in range(6)]
        assert r.winner_fit_score == r.winner.fit_score

    # ------------------------------------------------------------------ finished candidates

    def test_finished_candidates_are_kept_per_round_and_phase_in_arrival_order(self, job_store):
        job_id = running_job(job_store)
        commit_rounds(job_store, job_id, 1)
        round1 = hamming_round(1, job_store.get_job(job_id).current_state, 2).candidates
        failed = dataclasses.replace(round1[4], val_loss=math.nan, error="diverged")
        arrived = [FinishedCandidate(1, "train", round1[3], "sha256/" + "3" * 64),
                   FinishedCandidate(1, "train", failed, None),
                   FinishedCandidate(1, "halving", round1[3], "sha256/" + "a" * 64),
                   FinishedCandidate(1, "train", round1[0], "sha256/" + "0" * 64)]
        for finished in arrived:
            job_store.record_candidate(job_id, finished)
        job_store.record_candidate(job_id, arrived[0])  # recorded again after a retry: nothing changes
        assert job_store.finished_candidates(job_id, 1) == arrived
        assert job_store.finished_candidates(job_id, 1)[1].candidate.val_loss is None
        assert job_store.finished_candidates(job_id, 2) == []
        with pytest.raises(ConflictError, match="already recorded with different content"):
            job_store.record_candidate(job_id, dataclasses.replace(arrived[0], artifact_key="sha256/" + "9" * 64))
        other = running_job(job_store)
        assert job_store.finished_candidates(other, 1) == []  # per job
        with pytest.raises(NotFoundError):
            job_store.record_candidate("nope", arrived[0])

    def test_recording_a_candidate_charges_it_and_logs_it_in_one_transaction(self, job_backend):
        store = job_backend.open()
        job_id = running_job(store)
        commit_rounds(store, job_id, 1)
        candidate = hamming_round(1, store.get_job(job_id).current_state, 2).candidates[3]
        finished = FinishedCandidate(1, "train", candidate, "sha256/" + "3" * 64)
        job, events = store.get_job(job_id), store.events(job_id)
        with job_backend.refuse_events(), pytest.raises(InvalidRecordError, match="nothing was written"):
            store.record_candidate(job_id, finished, wall_s=2.0, cpu_s=4.0)
        assert store.finished_candidates(job_id, 1) == []  # none of the three
        assert store.get_job(job_id) == job and store.events(job_id) == events
        charged = store.record_candidate(job_id, finished, wall_s=2.0, cpu_s=4.0)
        assert (charged.used_wall_s, charged.used_cpu_s) == (2.0, 4.0) == (
            store.get_job(job_id).used_wall_s, store.get_job(job_id).used_cpu_s)
        assert store.finished_candidates(job_id, 1) == [finished]
        [event] = store.events(job_id, after_seq=events[-1].seq)
        assert event.kind == EventKind.CANDIDATE and event.payload == {
            "round": 1, "phase": "train", "state": candidate.state, "seed": candidate.seed,
            "train_loss": candidate.train_loss, "val_loss": candidate.val_loss, "fit_score": candidate.fit_score,
            "epochs": candidate.epochs, "wall_s": candidate.wall_s, "node": candidate.node, "error": None}
        # Again (a retry): nothing is written, not a second charge nor a second event; and a
        # different record under the same name changes nothing either.
        assert store.record_candidate(job_id, finished, wall_s=2.0, cpu_s=4.0) == store.get_job(job_id)
        with pytest.raises(ConflictError):
            store.record_candidate(job_id, dataclasses.replace(finished, artifact_key="sha256/" + "9" * 64),
                                   wall_s=1.0, cpu_s=1.0)
        with pytest.raises(InvalidRecordError, match="non-negative"):
            store.record_candidate(job_id, dataclasses.replace(finished, phase="halving"), cpu_s=-1.0)
        assert (store.get_job(job_id).used_wall_s, store.get_job(job_id).used_cpu_s) == (2.0, 4.0)
        assert len(store.events(job_id)) == len(events) + 1 and len(store.finished_candidates(job_id, 1)) == 1

    def test_a_finished_candidate_has_a_bundle_exactly_when_it_trained(self):
        ok = hamming_round(0, INITIAL, 1).candidates[0]
        with pytest.raises(InvalidRecordError, match="exactly when training succeeded"):
            FinishedCandidate(0, "train", ok, None)
        with pytest.raises(InvalidRecordError, match="exactly when training succeeded"):
            FinishedCandidate(0, "train", dataclasses.replace(ok, error="boom"), "sha256/" + "1" * 64)
        with pytest.raises(InvalidRecordError, match="phase"):
            FinishedCandidate(0, "", ok, "sha256/" + "1" * 64)

    def test_recovered_count_round_trips(self, job_store):
        job_id = running_job(job_store)
        record = dataclasses.replace(hamming_round(0, INITIAL, 1), recovered=4)
        job_store.commit_round(job_id, record)
        assert job_store.last_round(job_id).recovered == 4

    # ------------------------------------------------------------------------ usage, reason

    def test_usage_adds_up_and_survives_reopening(self, job_backend):
        store = job_backend.open()
        job_id = running_job(store)
        assert (store.get_job(job_id).used_wall_s, store.get_job(job_id).used_cpu_s) == (0.0, 0.0)
        store.charge(job_id, wall_s=1.5, cpu_s=3.0)
        job = store.charge(job_id, wall_s=0.25)
        assert (job.used_wall_s, job.used_cpu_s) == (1.75, 3.0)
        reopened = job_backend.open().get_job(job_id)
        assert (reopened.used_wall_s, reopened.used_cpu_s) == (1.75, 3.0)
        for bad in ({"wall_s": -1.0}, {"cpu_s": math.nan}, {"wall_s": math.inf}):
            with pytest.raises(InvalidRecordError, match="non-negative"):
                store.charge(job_id, **bad)
        assert store.get_job(job_id).used_wall_s == 1.75

    def test_preparations_are_counted_until_one_ends(self, job_backend):
        store = job_backend.open()
        job_id = job_in(store, S.PREPARING)
        assert store.get_job(job_id).unfinished_preparations == 0
        store.begin_preparation(job_id)
        assert store.begin_preparation(job_id).unfinished_preparations == 2
        assert job_backend.open().get_job(job_id).unfinished_preparations == 2  # survives a restart
        ended = store.end_preparation(job_id, EventKind.DATASET, {"key": "k", "materials": 2})
        assert ended.unfinished_preparations == 0 == store.get_job(job_id).unfinished_preparations
        assert store.begin_preparation(job_id).unfinished_preparations == 1
        assert store.end_preparation(job_id, EventKind.PREPARATION_INTERRUPTED).unfinished_preparations == 0
        kinds = [(e.kind, e.payload) for e in store.events(job_id)][-5:]
        assert kinds == [(EventKind.PREPARING, {}), (EventKind.PREPARING, {}),
                         (EventKind.DATASET, {"key": "k", "materials": 2}), (EventKind.PREPARING, {}),
                         (EventKind.PREPARATION_INTERRUPTED, {})]
        with pytest.raises(InvalidRecordError, match="a preparation ends as"):
            store.end_preparation(job_id, EventKind.COST)
        with pytest.raises(NotFoundError):
            store.begin_preparation("nope")

    def test_a_reason_is_recorded_with_a_terminal_status(self, job_store):
        job_id = running_job(job_store)
        with pytest.raises(InvalidRecordError, match="terminal"):
            job_store.set_status(job_in(job_store, S.QUEUED), S.PREPARING, reason="budget")
        job = job_store.set_status(job_id, S.STOPPED, reason="budget")
        assert (job.status, job.reason, job.error) == (S.STOPPED, "budget", None)
        assert job_store.events(job_id)[-1].payload["reason"] == "budget"

    def test_a_states_first_cost_is_kept_with_its_event(self, job_backend):
        store = job_backend.open()
        job_id = running_job(store)
        assert store.state_costs(job_id) == {}
        assert store.record_state_cost(job_id, "00100", 350.5) == 350.5
        assert store.record_state_cost(job_id, "00100", 999.0) == 350.5  # measured again: the first stays
        assert store.record_state_cost(job_id, "00000", 120) == 120.0
        assert job_backend.open().state_costs(job_id) == {"00100": 350.5, "00000": 120.0}  # survives a restart
        costs = [e.payload for e in store.events(job_id) if e.kind == EventKind.COST]
        assert costs == [{"state": "00100", "ns": 350.5}, {"state": "00000", "ns": 120.0}]  # one event each
        for state, ns, match in (("00100", 0.0, "positive"), ("00011", math.nan, "positive"),
                                 ("00011", math.inf, "positive"), ("00011", True, "positive"),
                                 ("0a", 1.0, "string of digits"), ("", 1.0, "string of digits")):
            with pytest.raises(InvalidRecordError, match=match):
                store.record_state_cost(job_id, state, ns)
        assert len(store.state_costs(job_id)) == 2
        with pytest.raises(NotFoundError):
            store.record_state_cost("nope", "00000", 1.0)
        with pytest.raises(NotFoundError):
            store.state_costs("nope")

    # ----------------------------------------------------------------------------- events

    def test_event_kinds_read_back_typed(self, job_store):
        job_id = job_in(job_store, S.QUEUED)
        job_store.append_event(job_id, EventKind.COST, {"state": "00000", "ns": 3.5})
        job_store.append_event(job_id, "note")  # a name of the caller's own
        created, cost, note = job_store.events(job_id)
        assert (created.kind, cost.kind, note.kind) == (EventKind.STATUS, EventKind.COST, "note")
        assert type(cost.kind) is EventKind and type(note.kind) is str

    def test_events_since_seq(self, job_store):
        job_id = job_in(job_store, S.QUEUED)  # event 1: created
        appended = [job_store.append_event(job_id, "candidate_done", {"state": f"{i:05b}", "i": i})
                    for i in range(5)]
        assert [e.seq for e in appended] == [2, 3, 4, 5, 6]
        assert job_store.events(job_id, after_seq=1) == appended
        assert job_store.events(job_id, after_seq=4) == appended[3:]
        assert job_store.events(job_id, after_seq=2, limit=2) == appended[1:3]
        assert job_store.events(job_id, after_seq=6) == []
        assert appended[0].payload == {"state": "00000", "i": 0} and appended[0].job_id == job_id
        assert all(a.time <= b.time for a, b in zip(appended, appended[1:]))

    @pytest.mark.parametrize("kind,payload", [("", {}), ("log", {"loss": math.nan}), ("log", {1: 2j})])
    def test_bad_events_are_rejected(self, job_store, kind, payload):
        job_id = job_in(job_store, S.QUEUED)
        with pytest.raises(InvalidRecordError):
            job_store.append_event(job_id, kind, payload)
        assert len(job_store.events(job_id)) == 1

    def test_threads_append_events_concurrently(self, job_store):
        job_id = job_in(job_store, S.QUEUED)
        n_threads, per_thread, errors = 8, 25, []

        def worker(t):
            try:
                for i in range(per_thread):
                    job_store.append_event(job_id, "log", {"thread": t, "i": i})
                    job_store.events(job_id, after_seq=0, limit=5)
            except Exception as exc:  # noqa: BLE001 - reported below
                errors.append(exc)

        threads = [threading.Thread(target=worker, args=(t,)) for t in range(n_threads)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert errors == []
        events = job_store.events(job_id)
        assert [e.seq for e in events] == list(range(1, n_threads * per_thread + 2))
        for t in range(n_threads):
            assert [e.payload["i"] for e in events if e.payload.get("thread") == t] == list(range(per_thread))


class TestRecords:
    """Validation of the read/write models themselves (no backend)."""

    def test_winner_must_be_a_candidate_with_a_finite_loss(self):
        good = hamming_round(0, INITIAL, 1)
        with pytest.raises(InvalidRecordError, match="not one of its candidates"):
            dataclasses.replace(good, winner_state="11111")
        with pytest.raises(InvalidRecordError, match="no candidates"):
            dataclasses.replace(good, candidates=())
        nan_winner = tuple(dataclasses.replace(c, val_loss=math.nan) if c.state == good.winner_state else c
                           for c in good.candidates)
        with pytest.raises(InvalidRecordError, match="no finite validation loss"):
            dataclasses.replace(good, candidates=nan_winner)

    @pytest.mark.parametrize("kind,reason", [(RoundKind.SEARCH, ""), (RoundKind.SEARCH, 3),
                                             (RoundKind.POLISH, "gain 0.1 %")])
    def test_a_stop_reason_is_text_on_a_search_round(self, kind, reason):
        outcome = S.STOPPED if kind is RoundKind.POLISH else None
        with pytest.raises(InvalidRecordError, match="stop reason"):
            dataclasses.replace(hamming_round(0, INITIAL, 1), kind=kind, outcome=outcome, stop_reason=reason)

    def test_candidate_fields_are_normalised(self):
        c = CandidateRecord(state="01", train_loss=1, val_loss=math.inf, epochs=3.0, wall_s=2,
                            extra={"k": (1, 2)}, fit_score=math.nan)
        assert (c.train_loss, c.val_loss, c.epochs, c.wall_s, c.extra, c.fit_score) == \
            (1.0, None, 3, 2.0, {"k": [1, 2]}, None)
        with pytest.raises(InvalidRecordError):
            CandidateRecord(state="", train_loss=1, val_loss=1, epochs=1, wall_s=1)
        assert isinstance(hamming_round(0, INITIAL, None).candidates, tuple)
        assert RoundRecord(0, "0", "0", [CandidateRecord("0", 1, 1, 1, 1)], 0, 1).winner_val_loss == 1.0
