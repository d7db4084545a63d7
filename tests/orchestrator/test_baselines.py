"""Fixed-state baselines trained with a search's data and budget."""

import dataclasses

import pytest

from neuenh.checkpoint import Bundle
from neuenh.modules import ModuleConfig
from neuenh.train import train_candidate
from neuenh_service.orchestrator.baselines import search_budget, train_like_search
from neuenh_service.orchestrator.dataset import prepare_dataset
from neuenh_service.storage import trained_epochs

from jobspecs import tiny_spec


def test_the_budget_is_the_epochs_the_final_state_trained(orchestrator, stores):
    jobs, _ = stores
    spec = tiny_spec(warmup_epochs=2, max_rounds=2, polish_epochs=3)
    job = orchestrator.run(orchestrator.submit(spec)[0].id)
    rounds = jobs.rounds(job.id)
    warmup, main, polish = search_budget(spec, rounds)
    assert (warmup, polish) == (2, 3) and main == len(rounds) - 1  # one epoch per search round
    assert warmup + main + polish == trained_epochs(rounds)
    with pytest.raises(ValueError, match="no committed round"):
        search_budget(spec, [])


def test_a_baseline_trains_in_the_search_stages(stores):
    """Warm-up in the analytical state, the state itself in pieces of one round's epochs (here
    2 + 1), then the polish: the same result as the ``train_candidate`` calls made by hand."""
    _, artifacts = stores
    spec = tiny_spec(polish_epochs=1, epochs_per_round=2)
    data, _ = prepare_dataset(spec, artifacts)
    config = ModuleConfig(choices=((8, 8),))
    state = "0000001000000"
    result = train_like_search(spec, data, (1, 3, 1), "ggx_residual", state, config)

    bundle = Bundle.initial("ggx_residual", data.names, config, spec.latent_dim)
    bundle = train_candidate(bundle, "0" * 13, data, spec.train_config(1), spec.train.seed).bundle
    bundle = train_candidate(bundle, state, data, spec.train_config(2), spec.train.seed + 1).bundle
    bundle = train_candidate(bundle, state, data, spec.train_config(1), spec.train.seed + 2).bundle
    expected = train_candidate(bundle, state, data, dataclasses.replace(spec.polish_config(), epochs=1),
                               spec.train.seed + 3)
    assert result.bundle.model.state == state and result.val_loss == expected.val_loss
    with pytest.raises(ValueError, match="trains nothing"):
        train_like_search(spec, data, (0, 0, 0), "ggx", "0" * 11, config)
