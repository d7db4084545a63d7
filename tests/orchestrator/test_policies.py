"""The search's policies (``orchestrator.policies``) on their own, with a recording stand-in for
training: which tasks each policy trains, from which parent, in which phase."""

from __future__ import annotations

import pytest

from neuenh_service.orchestrator.executor import CandidateReport, CandidateTask
import math

from neuenh_service.orchestrator.policies import (ByFitScore, SuccessiveHalving, TrainEvery, ByValLoss,
                                                     round_pruning, selection_score)
from neuenh_service.orchestrator.spec import parse_spec

LOSS = {"a": 0.4, "b": 0.1, "c": 0.3, "d": 0.2}  # the better half: b and d


class Recorder:
    """``Train``: a candidate's loss is LOSS[state] less a thousandth per epoch; its bundle names it."""

    def __init__(self):
        self.calls = []

    def __call__(self, parents, tasks, phase):
        self.calls.append((phase, [(t.state, t.epochs, parents[t.parent]) for t in tasks]))
        return [CandidateReport(t, 0.0, LOSS[t.state] - t.epochs / 1000, t.epochs, 1.0, "here",
                                bundle=f"{t.state}@{t.epochs}".encode()) for t in tasks]


def better_half(reports):
    return [r.task.state for r in sorted(reports, key=lambda r: r.val_loss)[:len(reports) // 2]]


def tasks(states, epochs=10):
    return [CandidateTask(s, seed=i, epochs=epochs) for i, s in enumerate(states)]


def test_train_every_trains_each_task_once_in_full():
    train = Recorder()
    trained = TrainEvery().train_round(train, better_half, b"parent", tasks("abcd"))
    assert train.calls == [("train", [(s, 10, b"parent") for s in "abcd"])]
    assert [r.task.state for r in trained.reports] == list("abcd")
    assert (trained.halving, trained.pruned) == (None, frozenset())


def test_successive_halving_continues_the_better_half_from_their_own_bundles():
    train = Recorder()
    trained = SuccessiveHalving(0.3).train_round(train, better_half, b"parent", tasks("abcd"))
    assert train.calls == [("halving", [(s, 3, b"parent") for s in "abcd"]),
                           ("continue", [("b", 7, b"b@3"), ("d", 7, b"d@3")])]
    assert [(r.task.state, r.epochs) for r in trained.reports] == [("a", 3), ("b", 10), ("c", 3), ("d", 10)]
    assert trained.pruned == {"a", "c"}
    assert trained.halving.first_epochs == 3 and trained.halving.early_val_loss == pytest.approx(
        {s: LOSS[s] - 0.003 for s in "abcd"})


def test_successive_halving_trains_every_one_of_two_candidates():
    train = Recorder()
    trained = SuccessiveHalving(0.3).train_round(train, better_half, b"parent", tasks("ab"))
    assert [phase for phase, _ in train.calls] == ["train"] and trained.pruned == frozenset()


@pytest.mark.parametrize("prune,policy", [("none", TrainEvery), ("halving", SuccessiveHalving)])
def test_the_spec_names_the_policy(prune, policy):
    spec = parse_spec({"data": [{"source": "synthetic_zoo", "materials": 2, "samples": 10}],
                       "search": {"prune": prune, "halving_fraction": 0.25}})
    chosen = round_pruning(spec)
    assert type(chosen) is policy and getattr(chosen, "fraction", 0.25) == 0.25


def test_the_selecting_loss_is_the_val_loss_or_the_fit_score_a_candidate_without_one_ineligible():
    scored = CandidateReport(CandidateTask("a", 0, 1), 0.5, 0.25, 1, 1.0, "here", fit_score=0.125)
    unscored = CandidateReport(CandidateTask("b", 0, 1), 0.5, 0.25, 1, 1.0, "here")
    assert (ByValLoss().loss(scored), ByFitScore().loss(scored)) == (0.25, 0.125)
    assert ByValLoss().loss(unscored) == 0.25 and math.isnan(ByFitScore().loss(unscored))
    data = [{"source": "synthetic_zoo", "materials": 4, "samples": 10, "holdout": 2}]
    assert type(selection_score(parse_spec({"data": data}))) is ByValLoss
    assert type(selection_score(parse_spec({"data": data, "search": {"score": "fit"}}))) is ByFitScore
