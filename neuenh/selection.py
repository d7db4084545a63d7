"""Selection by generalisation: score a trained candidate the way users use the model (issue 23).

A search's validation loss measures held-out *samples* of its training materials, whose parameters
were trained jointly with the modules; it rewards capacity. Users fit *new* materials with the
modules frozen. The fit score measures exactly that, on materials of the training sources that
training never saw (``TrainingData.holdout``, a data source's ``holdout``):

    fit_score = 1/|H| sum_{m in H} mean_{k in test(m)} | log(1 + f_m,k cos_i) - log(1 + f^_m(wi_k, wo_k) cos_i) |

where ``f^_m`` is the candidate with its module weights frozen and material ``m``'s analytical and
latent parameters fitted (``fit.fit_materials``, ``FitScoreConfig.epochs``, starting from the mean
latent code of the candidate's training materials; with ``FitScoreConfig.capacity`` ``auto`` also
module corrections where its own cross-validation chooses them, as ``neuenh fit`` does) to
``fit(m)``, ``FitScoreConfig.fit_samples`` of ``m``'s samples, and ``test(m)`` up to
``test_samples`` of its other samples (one seeded permutation per material, ``split_materials``):
the paper's loss (``train.log_l1``) on pairs the fit never saw, averaged per material and then over
materials, so every held-out material counts alike.

``train_and_score`` is what a search worker runs: ``train.train_candidate``, then this score when
the training config asks for it and the data holds out materials. Both are pure functions of their
inputs: the same inputs give the same score on the same CPU with the same thread count.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import torch

from .checkpoint import Bundle
from .data.samples import Samples, TrainingData
from .fit import FitOptions, FitProtocol, fit_materials, losses_at_own_capacity
from .materials import MaterialTable
from .model import BRDFModel
from .train import CandidateResult, FitScoreConfig, TrainConfig, train_candidate

__all__ = ["FitScore", "FitScoreConfig", "fit_score", "split_materials", "train_and_score"]


@dataclass(frozen=True)
class FitScore:
    score: float  # the mean over held-out materials of their held-out log-L1
    per_material: tuple[float, ...]  # in the held-out samples' ``names`` order
    wall_s: float  # the fits and the measurement


def split_materials(samples: Samples, fit_samples: int, test_samples: int, seed: int) -> tuple[Samples, Samples]:
    """(fit, test): per material, one permutation seeded with ``seed`` and the material's index gives
    the first ``fit_samples`` rows to fit and the next ``test_samples`` to test — disjoint rows. A
    material needs more than ``fit_samples`` rows (at least one to test)."""
    fit_rows, test_rows = [], []
    for i, name in enumerate(samples.names):
        rows = torch.nonzero(samples.material == i).squeeze(1)
        if len(rows) <= fit_samples:
            raise ValueError(f"held-out material {name!r} has {len(rows)} samples; scoring fits {fit_samples} "
                             "of them and needs at least one more to measure on")
        order = rows[torch.randperm(len(rows), generator=torch.Generator().manual_seed(seed * 100_003 + i))]
        fit_rows.append(order[:fit_samples])
        test_rows.append(order[fit_samples : fit_samples + test_samples])
    return samples.subset(torch.cat(fit_rows)), samples.subset(torch.cat(test_rows))


def score_protocol(model: BRDFModel, config: FitScoreConfig) -> FitProtocol:
    """The fit ``fit_score`` gives each held-out material: the users' protocol at ``config``'s capacity and
    budget, on torch's kernel — the score runs inside a candidate's task, whose CPU share torch's threads
    keep, where Dr.Jit's pool would take every core of the node."""
    return FitOptions(capacity=config.capacity, epochs=config.epochs, lbfgs_iterations=config.epochs,
                      kernel="torch").protocol_for(model)


def fit_score(model: BRDFModel, holdout: Samples, config: FitScoreConfig = FitScoreConfig(),
              trained: MaterialTable | None = None) -> FitScore:
    """Score ``model`` on the held-out materials ``holdout`` (module doc); ``trained``: the
    candidate's training materials, whose mean latent code is a start of each fit."""
    start = time.perf_counter()
    fit, test = split_materials(holdout, config.fit_samples, config.test_samples, config.seed)
    result = fit_materials(model, fit, score_protocol(model, config), seed=config.seed, trained=trained)
    losses = losses_at_own_capacity(model, result.materials, test)  # each at the capacity its fit chose
    return FitScore(float(sum(losses) / len(losses)), tuple(losses), time.perf_counter() - start)


def train_and_score(parent: Bundle, state: str, data: TrainingData, config: TrainConfig, seed: int) -> CandidateResult:
    """``train.train_candidate``; then, when ``config.fit_score`` is set, the data holds out
    materials and training succeeded, the trained candidate's ``fit_score`` (also written into its
    bundle's metrics; its time is added to ``wall_s`` and kept in ``fit_score_s``)."""
    result = train_candidate(parent, state, data, config, seed)
    if config.fit_score is None or data.holdout is None or not result.ok:
        return result
    scored = fit_score(result.bundle.model, data.holdout, config.fit_score, trained=result.bundle.materials)
    result.fit_score = scored.score
    result.bundle.metrics["fit_score"] = scored.score
    result.wall_s += scored.wall_s
    result.fit_score_s = scored.wall_s
    return result
