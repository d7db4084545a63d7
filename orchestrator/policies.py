"""The search's policies as objects, the way Optuna keeps samplers and pruners: how a round trains
its candidates (``search.prune``), which loss selects (``search.score``) and what a candidate's
complexity costs (``search.cost``).

``JobRun`` builds one of each from the spec when it starts (``round_pruning``, ``selection_score``,
``cost_policy``) and asks it; a new policy is a class here and a name in ``spec.SearchSpec``.
Policies know nothing of the run beyond what they are handed: a ``Train`` callable and a ranking of reports.
"""

from __future__ import annotations

import dataclasses
from abc import ABC, abstractmethod
from collections.abc import Callable

from neuenh.checkpoint import Bundle
from neuenh.scene.ladder import measure_cost
from neuenh.search import weight_cost
from neuenh_service.storage import HalvingRecord, JobStore

from .executor import CandidateReport, CandidateTask
from .spec import JobSpec, neural_weights

#: ``train(parents, tasks, phase)``: every task trained from ``parents[task.parent]``, reports in the
#: tasks' order (``JobRun.train`` bound to the round and its training config).
Train = Callable[[list[bytes], list[CandidateTask], str], list[CandidateReport]]
#: ``better_half(reports)``: the states of the reports that go on (``neuenh.search.keep_better_half``).
BetterHalf = Callable[[list[CandidateReport]], list[str]]


@dataclasses.dataclass(frozen=True)
class TrainedRound:
    """A round's candidates trained: every report in the tasks' order, and with pruning its record
    and the states it pruned (whose reports are from the cut)."""

    reports: list[CandidateReport]
    halving: HalvingRecord | None = None
    pruned: frozenset[str] = frozenset()


class RoundPruning(ABC):
    """How a search round trains its candidates (``search.prune``)."""

    @abstractmethod
    def train_round(self, train: Train, better_half: BetterHalf, parent: bytes,
                    tasks: list[CandidateTask]) -> TrainedRound:
        """Every task trained from ``parent``, each to its ``epochs`` unless pruned on the way."""


class TrainEvery(RoundPruning):
    """``prune: none``: every candidate trains all its epochs."""

    def train_round(self, train, better_half, parent, tasks):
        return TrainedRound(train([parent], tasks, "train"))


@dataclasses.dataclass(frozen=True)
class SuccessiveHalving(RoundPruning):
    """``prune: halving``: every candidate trains ``fraction`` of the epochs, the better half goes on
    from there; the pruned keep their early reports. Rounds of two candidates or fewer train every one."""

    fraction: float

    def train_round(self, train, better_half, parent, tasks):
        if len(tasks) <= 2:
            return TrainEvery().train_round(train, better_half, parent, tasks)
        epochs = tasks[0].epochs
        first = max(1, round(epochs * self.fraction))
        early = train([parent], [dataclasses.replace(t, epochs=first) for t in tasks], "halving")
        by_state = {r.task.state: r for r in early}
        second = [CandidateTask(state, by_state[state].task.seed, epochs - first, parent=i)
                  for i, state in enumerate(better_half(early))]
        late = train([by_state[t.state].bundle for t in second], second, "continue")
        late_by_state = {r.task.state: dataclasses.replace(r, epochs=r.epochs + first) for r in late}
        return TrainedRound(reports=[late_by_state.get(r.task.state, r) for r in early],
                            halving=HalvingRecord(first_epochs=first,
                                                  early_val_loss={r.task.state: r.val_loss for r in early}),
                            pruned=frozenset(r.task.state for r in early if r.task.state not in late_by_state))


def round_pruning(spec: JobSpec) -> RoundPruning:
    search = spec.search
    return SuccessiveHalving(search.halving_fraction) if search.prune == "halving" else TrainEvery()


class SelectionScore(ABC):
    """Which loss selects a round's winner and ends a search (``search.score``)."""

    name: str  # what the loss is called in messages
    label: str  # ... and on a progress line

    @abstractmethod
    def loss(self, report: CandidateReport) -> float:
        """The candidate's selecting loss; NaN when it has none (not eligible)."""


class ByValLoss(SelectionScore):
    """``score: val``: the validation loss on held-out samples of the training materials."""

    name = "validation loss"
    label = "val"

    def loss(self, report):
        return report.val_loss


class ByFitScore(SelectionScore):
    """``score: fit``: the fit score on the materials the job held out (``neuenh.selection``)."""

    name = label = "fit score"

    def loss(self, report):
        return float("nan") if report.fit_score is None else report.fit_score


def selection_score(spec: JobSpec) -> SelectionScore:
    return ByFitScore() if spec.search.score == "fit" else ByValLoss()


class CostPolicy(ABC):
    """What a trained candidate's complexity costs, for ``search.complexity_weight``."""

    @abstractmethod
    def cost(self, report: CandidateReport) -> float:
        """The cost of the (successfully trained) candidate of ``report``."""


@dataclasses.dataclass(frozen=True)
class WeightCost(CostPolicy):
    """``cost: weights``: the neural weights the state adds (``neuenh.search.weight_cost``)."""

    spec: JobSpec

    def cost(self, report):
        return weight_cost(neural_weights(self.spec, report.task.state))


class TimeCost(CostPolicy):
    """``cost: time``: the specialized evaluation's time, in units of 100 ns, measured once per state
    of the job and kept by the job store (``JobStore.record_state_cost``); after a restart the kept
    numbers are read back, so a resumed job makes the same choices."""

    def __init__(self, jobs: JobStore, job_id: str) -> None:
        self.jobs, self.job_id = jobs, job_id
        self._ns: dict[str, float] | None = None  # state -> measured nanoseconds, read lazily

    def cost(self, report):
        if self._ns is None:
            self._ns = self.jobs.state_costs(self.job_id)
        state = report.task.state
        if state not in self._ns:
            measured = evaluation_cost_ns(Bundle.from_bytes(report.bundle))
            self._ns[state] = self.jobs.record_state_cost(self.job_id, state, measured)
        return self._ns[state] / 100.0


def cost_policy(spec: JobSpec, jobs: JobStore, job_id: str) -> CostPolicy:
    return WeightCost(spec) if spec.search.cost == "weights" else TimeCost(jobs, job_id)


def evaluation_cost_ns(bundle: Bundle) -> float:
    """Nanoseconds per evaluation of a candidate's specialized BRDF on its first training material."""
    return measure_cost(bundle.model.specialize(bundle.materials.as_params(0)))
