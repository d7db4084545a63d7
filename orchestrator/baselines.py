"""Baselines trained on a search's data with the search's budget (issue 6).

A search trains its final state, in all, ``trained_epochs(rounds)`` epochs: the warm-up in the
analytical state, one round's epochs per committed round, and the polish. A fixed-state baseline
(the residual MLPs appended to GGX, the all-positions-neural state) gets exactly that: the same
data, the same optimiser and lr schedule, the same number of epochs in the same three stages — the
analytical state for the warm-up, its own state for the rounds' epochs (one cosine, as a round
trains), then the polish — so a comparison with the enhanced model differs only in the state.
"""

from __future__ import annotations

import dataclasses

from neuenh.checkpoint import Bundle
from neuenh.modules import ModuleConfig
from neuenh.train import CandidateResult, TrainingData, train_candidate
from storage import RoundRecord

from .runner import trained_epochs
from .spec import JobSpec

__all__ = ["search_budget", "train_like_search"]


def search_budget(spec: JobSpec, rounds: list[RoundRecord]) -> tuple[int, int, int]:
    """(warm-up, rounds, polish) epochs the final state of a search trained; they sum to
    ``trained_epochs(rounds)``."""
    if not rounds:
        raise ValueError("the search has no committed round")
    warmup = rounds[0].extra.get("warmup", {}).get("epochs", 0)
    polish = rounds[-1].winner.epochs if rounds[-1].extra.get("polish") else 0
    total = trained_epochs(rounds)
    return warmup, total - warmup - polish, polish


def train_like_search(spec: JobSpec, data: TrainingData, budget: tuple[int, int, int], model: str, state: str,
                      module_config: ModuleConfig) -> CandidateResult:
    """Train ``state`` of ``model`` (modules ``module_config``) on ``data`` with the stages of
    ``budget`` (:func:`search_budget`), seeded by the spec; returns the last stage's result (its
    ``epochs`` is the last stage's, the bundle has trained all of them)."""
    warmup, main, polish = budget
    bundle = Bundle.initial(model, data.names, module_config, spec.latent_dim)
    zero = "0" * len(bundle.model.positions)
    stages = [(zero, spec.train_config(warmup)), (state, spec.train_config(main)),
              (state, dataclasses.replace(spec.polish_config(), epochs=polish))]
    result = None
    for i, (stage_state, config) in enumerate(stages):
        if config.epochs == 0:
            continue
        result = train_candidate(bundle, stage_state, data, config, spec.train.seed + i)
        if result.error:
            raise RuntimeError(f"training {model} {stage_state} failed: {result.error}")
        bundle = result.bundle
    if result is None:
        raise ValueError(f"a budget of {budget} epochs trains nothing")
    return result
