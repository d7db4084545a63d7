"""Baselines trained on a search's data with the search's budget (issue 6).

A search trains its final state, in all, ``trained_epochs(rounds)`` epochs: the warm-up in the
analytical state, one round's epochs per committed round (each round's training restarts the lr
schedule), and the polish. A fixed-state baseline (the residual MLPs appended to GGX, the
all-positions-neural state) is trained exactly that way (:func:`training_stages`): the warm-up in
its analytical state, then its own state for as many rounds of ``epochs_per_round`` as the search
ran, then the polish — same data, optimiser and schedules — so a comparison with the enhanced model
differs only in the state.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path

from neuenh.checkpoint import Bundle
from neuenh.modules import ModuleConfig
from neuenh.train import CandidateResult, TrainConfig, train_candidate
from neuenh.data.samples import TrainingData
from neuenh.study.registry import BASELINES
from neuenh_service.storage import LocalArtifactStore, RoundKind, RoundRecord, trained_epochs

from .spec import JobSpec

__all__ = ["search_budget", "train_like_search", "train_missing_baselines", "training_stages"]


def search_budget(spec: JobSpec, rounds: list[RoundRecord]) -> tuple[int, int, int]:
    """(warm-up, rounds, polish) epochs the final state of a search trained; they sum to
    ``trained_epochs(rounds)``."""
    if not rounds:
        raise ValueError("the search has no committed round")
    warmup = rounds[0].warmup.epochs if rounds[0].warmup else 0
    polish = rounds[-1].winner.epochs if rounds[-1].kind is RoundKind.POLISH else 0
    total = trained_epochs(rounds)
    return warmup, total - warmup - polish, polish


def training_stages(spec: JobSpec, budget: tuple[int, int, int], positions: int,
                    state: str) -> list[tuple[str, TrainConfig, int]]:
    """(state, config, seed) of each stage, in order: the warm-up (all-zero state), the rounds'
    epochs cut into ``epochs_per_round`` pieces (the last one shorter if they do not divide), then
    the polish; stages of no epochs are left out."""
    warmup, main, polish = budget
    per_round = spec.search.epochs_per_round
    pieces = [per_round] * (main // per_round) + ([main % per_round] if main % per_round else [])
    stages = [("0" * positions, spec.train_config(warmup))]
    stages += [(state, spec.train_config(epochs)) for epochs in pieces]
    stages.append((state, dataclasses.replace(spec.polish_config(), epochs=polish)))
    return [(s, config, spec.train.seed + i) for i, (s, config) in enumerate(stages) if config.epochs]


def train_like_search(spec: JobSpec, data: TrainingData, budget: tuple[int, int, int], model: str, state: str,
                      module_config: ModuleConfig) -> CandidateResult:
    """Train ``state`` of ``model`` (modules ``module_config``) on ``data`` through the stages of
    ``budget`` (:func:`training_stages`); returns the last stage's result (its bundle has trained
    every stage)."""
    bundle = Bundle.initial(model, data.names, module_config, spec.latent_dim)
    stages = training_stages(spec, budget, len(bundle.model.positions), state)
    if not stages:
        raise ValueError(f"a budget of {budget} epochs trains nothing")
    for stage_state, config, seed in stages:
        result = train_candidate(bundle, stage_state, data, config, seed)
        if result.error:
            raise RuntimeError(f"training {model} {stage_state} failed: {result.error}")
        bundle = result.bundle
    return result


def train_missing_baselines(spec_path: Path, budget: tuple[int, int, int] | None, baselines: Path,
                            work_dir: Path) -> None:
    """Every baseline of the study (``neuenh.study.registry.BASELINES``) not yet under ``baselines``
    trained like the search on the data of the job spec at ``spec_path`` (cached under ``work_dir``),
    with ``budget`` (the enhanced model's recorded search budget), and saved with its provenance."""
    from .dataset import prepare_dataset
    from .spec import load_spec

    missing = [b for b in BASELINES.values() if not (b.bundle_dir(baselines) / "model.json").is_file()]
    if not missing:
        return
    if not budget:
        raise ValueError("the enhanced model's provenance records no search budget to train baselines with")
    spec = load_spec(spec_path)
    data, _ = prepare_dataset(spec, LocalArtifactStore(work_dir / "artifacts"))
    for b in missing:
        print(f"training {b.name} ({b.label}) for {sum(budget)} epochs ...", file=sys.stderr)
        start = time.perf_counter()
        result = train_like_search(spec, data, tuple(budget), b.model, b.state, b.module_config(spec.module.config()))
        result.bundle.provenance = {"baseline": b.name, "label": b.label, "spec": str(spec_path),
                                    "budget": list(budget), "train_s": round(time.perf_counter() - start, 1)}
        result.bundle.save(b.bundle_dir(baselines))
        print(f"  {b.name}: val log-L1 {result.val_loss:.5f}", file=sys.stderr)
