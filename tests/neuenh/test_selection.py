"""Selection by generalisation (neuenh.selection): candidates scored by fitting materials kept out of training."""

import numpy as np
import pytest
import torch

from neuenh.checkpoint import Bundle
from neuenh.data.samples import sample_materials
from neuenh.data.sources import SyntheticGGX, SyntheticZoo, materialise
from neuenh.data.synthetic import synthetic_ggx
from neuenh.models import get_model
from neuenh.selection import FitScoreConfig, fit_score, split_materials, train_and_score
from neuenh.train import TrainConfig

SCORE = FitScoreConfig(fit_samples=150, test_samples=200, epochs=10)


@pytest.fixture(scope="module")
def held_out_data():
    """2 zoo materials and 1 GGX material to train on, 1 of each held out (400 samples each)."""
    return materialise([SyntheticZoo(source="synthetic_zoo", materials=3, samples=400, seed=1, holdout=1),
                        SyntheticGGX(source="synthetic_ggx", materials=2, samples=400, seed=2, holdout=1)],
                       val_fraction=0.1, seed=0)


def test_the_split_gives_each_material_disjoint_fit_and_test_rows():
    samples = sample_materials(synthetic_ggx(3, seed=0), 50, seed=1)
    fit, test = split_materials(samples, fit_samples=20, test_samples=100, seed=4)
    for i in range(3):
        rows = lambda part: {tuple(x) for x in torch.cat([part.wi, part.wo], 1)[part.material == i].tolist()}  # noqa: E731
        assert len(rows(fit)) == 20 and len(rows(test)) == 30  # the rest, fewer than test_samples
        assert not rows(fit) & rows(test)
    again, _ = split_materials(samples, 20, 100, seed=4)
    assert torch.equal(fit.wi, again.wi)
    with pytest.raises(ValueError, match="ggx-000.*50 samples.*fits 50"):
        split_materials(samples, 50, 10, seed=0)


def test_a_model_of_the_right_form_scores_near_zero_and_one_of_the_wrong_form_does_not():
    """Noise-free GGX materials: plain GGX fitted to them reproduces them, so its held-out log-L1 is the
    fit's residual; Ward cannot represent a GGX lobe. The score is measured on rows the fit never saw."""
    samples = sample_materials(synthetic_ggx(2, seed=3, noise_sigma=0.0), 500, seed=5)
    config = FitScoreConfig(fit_samples=300, test_samples=200, epochs=40)
    ggx, ward = fit_score(get_model("ggx"), samples, config), fit_score(get_model("ward"), samples, config)
    assert len(ggx.per_material) == 2 and ggx.score == pytest.approx(np.mean(ggx.per_material))
    assert ggx.score < 0.1 * ward.score


def test_a_score_at_the_users_capacity_measures_each_material_as_its_own_fit_left_it():
    """``capacity="auto"``: each held-out material fitted as ``neuenh fit`` does by default, and its
    score the log-L1 of what its own fit chose (corrections folded in, or the analytical model) —
    measured here by another path, each fitted record specialized (``neuenh.specialize``, the
    exporters' walker) and evaluated in float64 on the test rows."""
    from neuenh.fit import FitOptions, fit_materials, material_model

    model = get_model("ggx", state="00010001000", seed=3)  # F and the operator S*D*F neural
    samples = sample_materials(synthetic_ggx(2, seed=3, noise_sigma=0.05), 500, seed=5)
    config = FitScoreConfig(fit_samples=300, test_samples=200, epochs=6, capacity="auto")
    scored = fit_score(model, samples, config)
    fit, test = split_materials(samples, 300, 200, config.seed)
    options = FitOptions(capacity="auto", epochs=6, lbfgs_iterations=6)
    table = fit_materials(model, fit, options.protocol_for(model), seed=config.seed).materials
    by_hand, chosen = [], []
    for i in range(2):
        own, params = material_model(model, table, i)
        chosen.append(params.capacity)
        rows = test.of_material(i)
        wi, wo, f_r = (t.double() for t in (rows.wi, rows.wo, rows.f_r))
        pred = own.specialize(params)(wi, wo)
        cos = wi[:, 2:3].clamp_min(0)
        by_hand.append(float((torch.log1p(f_r * cos) - torch.log1p(pred * cos)).abs().mean()))
    assert any(c not in ("latent", None) for c in chosen), chosen  # a capacity a latent-only score cannot measure
    # the score runs in float32 against float64 here: ~100 roundings an evaluation, each within eps of f_r,
    # and |d log(1 + f cos)| <= |df / f|, so each sample's loss moves by at most ~100 eps
    rounding = 100 * torch.finfo(torch.float32).eps
    assert scored.per_material == pytest.approx(by_hand, abs=rounding)
    assert scored.score == pytest.approx(np.mean(by_hand), abs=rounding)
    with pytest.raises(ValueError, match="invalid fit score config"):
        FitScoreConfig(capacity="rank-8")


def test_a_candidate_is_scored_on_materials_it_never_trained_on(held_out_data):
    data = held_out_data
    assert data.holdout is not None and len(data.holdout.names) == 2
    assert not set(data.holdout.names) & set(data.names)
    parent = Bundle.initial("ggx", data.names)
    config = TrainConfig(epochs=2, batch_size=1000, fit_score=SCORE)
    a = train_and_score(parent, "00001000000", data, config, seed=3)
    assert a.ok and a.fit_score is not None and np.isfinite(a.fit_score)
    assert a.bundle.materials.names == data.names  # the held-out ones are not among its materials
    assert a.bundle.metrics["fit_score"] == a.fit_score
    b = train_and_score(parent, "00001000000", data, config, seed=3)
    assert (a.val_loss, a.fit_score) == (b.val_loss, b.fit_score)  # deterministic
    # By hand: the trained candidate's score is fit_score of its model on the held-out samples.
    direct = fit_score(a.bundle.model, data.holdout, SCORE, trained=a.bundle.materials)
    assert direct.score == a.fit_score


def test_without_held_out_materials_or_a_score_config_there_is_no_score(held_out_data, small_data):
    parent = Bundle.initial("ggx", small_data.names)
    assert train_and_score(parent, "00000000000", small_data, TrainConfig(epochs=1, batch_size=2000, fit_score=SCORE),
                           seed=0).fit_score is None
    parent = Bundle.initial("ggx", held_out_data.names)
    assert train_and_score(parent, "00000000000", held_out_data, TrainConfig(epochs=1, batch_size=2000),
                           seed=0).fit_score is None
