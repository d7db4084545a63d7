import pytest
import torch

from neuenh.data.samples import sample_materials
from neuenh.data.synthetic import synthetic_ggx
from neuenh.fit import FitConfig, fit_materials, per_material_loss
from neuenh.models import get_model
from ggx_states import PAPER_STATE


@pytest.fixture(scope="module")
def clean_ggx():
    (material,) = synthetic_ggx(1, seed=21, noise_sigma=0.0)
    return material, sample_materials([material], 5000, seed=0)


def test_fast_fit_recovers_a_ggx_material(clean_ggx):
    material, samples = clean_ggx
    result = fit_materials(get_model("ggx"), samples)
    assert result.loss < 0.01
    truth = material.metadata["params"]
    fitted = {k: v[0].tolist() for k, v in result.materials.values().items()}
    # Roughnesses up to the symmetry (alpha_x, alpha_y, t) ~ (alpha_y, alpha_x, t +- pi/2).
    assert sorted(fitted["alpha_x"] + fitted["alpha_y"]) == pytest.approx(
        sorted(truth["alpha_x"] + truth["alpha_y"]), rel=0.15)
    assert fitted["rho_d"] == pytest.approx(truth["rho_d"], abs=0.05)


def test_fast_fit_beats_the_paper_protocol_at_the_same_epoch_budget(clean_ggx):
    _, samples = clean_ggx
    model = get_model("ggx")
    fast = fit_materials(model, samples, FitConfig(epochs=60))
    paper = fit_materials(model, samples, FitConfig(method="paper", epochs=60))
    assert fast.loss < 0.5 * paper.loss


def test_paper_protocol_defaults():
    config = FitConfig(method="paper")
    assert (config.resolved_epochs, config.resolved_lr) == (1000, 1e-3)
    with pytest.raises(ValueError, match="fit method"):
        FitConfig(method="newton")


def test_fitting_leaves_module_weights_frozen(clean_ggx):
    _, samples = clean_ggx
    model = get_model("ggx", state=PAPER_STATE, seed=0)
    before = {k: v.clone() for k, v in model.state_dict().items()}
    result = fit_materials(model, samples, FitConfig(epochs=5))
    for key, value in model.state_dict().items():
        assert torch.equal(value, before[key])
    assert all(p.requires_grad for p in model.parameters())
    assert not torch.equal(result.materials.latent, torch.full_like(result.materials.latent, 0.5))


@pytest.fixture(scope="module")
def two_zoo_materials():
    from neuenh.data.synthetic import synthetic_zoo

    return sample_materials(synthetic_zoo(2, seed=5), 3000, seed=1)


def test_enhanced_fits_keep_the_best_start_per_material(two_zoo_materials):
    """``starts="analytical"`` fits the paper's start among others (one from the training
    materials' mean latent code) and keeps, per material, the lowest fit loss: with the paper
    protocol (every start to the end) never worse than the paper's start alone, and the losses
    are those of the returned parameters (both protocols)."""
    from neuenh.materials import MaterialTable

    samples = two_zoo_materials
    model = get_model("ggx", state="00010001000", seed=3)
    trained = MaterialTable(model.specs, ("t1", "t2"), model.latent_dim, latent=torch.tensor([[0.1] * 27, [0.3] * 27]))
    paper = fit_materials(model, samples, FitConfig(method="paper", epochs=30, starts="paper"))
    best = fit_materials(model, samples, FitConfig(method="paper", epochs=30), trained=trained)
    for mine, theirs in zip(best.losses, paper.losses):
        assert mine <= theirs
    assert per_material_loss(model, best.materials, samples) == pytest.approx(best.losses, rel=1e-6)
    fast = fit_materials(model, samples, FitConfig(epochs=40), trained=trained)
    assert per_material_loss(model, fast.materials, samples) == pytest.approx(fast.losses, rel=1e-6)


def test_stacked_adam_narrows_to_each_materials_best_start():
    """Two materials, two starts each: the true parameters of one material are a start of that
    material only. After ``NARROW_AT`` of the epochs each material keeps its better start, so both
    end near zero loss, and the result has one row per material."""
    from neuenh.fit import _stack, adam_rows
    from neuenh.materials import MaterialTable

    materials = synthetic_ggx(2, seed=4, noise_sigma=0.0)
    samples = sample_materials(materials, 2000, seed=2)
    model = get_model("ggx")
    truth = {s.name: torch.stack([s.to_raw(torch.as_tensor(m.metadata["params"][s.name], dtype=torch.float64))
                                  for m in materials]).float() for s in model.specs}
    default = MaterialTable(model.specs, samples.names, model.latent_dim)
    start_a = MaterialTable(model.specs, samples.names, model.latent_dim,  # material 0 true, 1 default
                            {k: torch.stack([v[0], default.raw[k].detach()[1]]) for k, v in truth.items()})
    start_b = MaterialTable(model.specs, samples.names, model.latent_dim,  # material 0 default, 1 true
                            {k: torch.stack([default.raw[k].detach()[0], v[1]]) for k, v in truth.items()})
    stacked, table = _stack(samples, [start_a, start_b])
    config = FitConfig(epochs=8, lr=1e-4)  # small steps: the true starts stay near zero loss
    result, ended_on, _ = adam_rows(model, stacked, table, config, starts=2)
    assert len(result) == 2 and len(ended_on) == len(samples)
    losses = per_material_loss(model, result, samples)
    assert max(losses) < 1e-3 < min(per_material_loss(model, default, samples))


def test_stacked_rows_do_not_depend_on_each_other():
    """A start fitted alone and stacked with another start (no narrowing) ends at the same
    parameters: each row's objective is its own mean loss."""
    from neuenh.fit import _stack, adam_rows
    from neuenh.materials import MaterialTable

    samples = sample_materials(synthetic_ggx(1, seed=8, noise_sigma=0.0), 1500, seed=3)
    model = get_model("ggx", state=PAPER_STATE, seed=1)
    config = FitConfig(epochs=15)
    alone = MaterialTable(model.specs, samples.names, model.latent_dim)
    other = MaterialTable(model.specs, samples.names, model.latent_dim, latent=torch.full((1, 27), -0.3))
    adam_rows(model, samples, alone, config)
    stacked, table = _stack(samples, [MaterialTable(model.specs, samples.names, model.latent_dim), other])
    adam_rows(model, stacked, table, config)
    torch.testing.assert_close(table.latent.detach()[:1], alone.latent.detach(), rtol=1e-4, atol=1e-5)
    for name, raw in alone.raw.items():
        torch.testing.assert_close(table.raw[name].detach()[:1], raw.detach(), rtol=1e-4, atol=1e-5)


def test_an_analytical_model_has_one_start(clean_ggx):
    _, samples = clean_ggx
    model = get_model("ggx")
    one = fit_materials(model, samples, FitConfig(epochs=20))
    paper = fit_materials(model, samples, FitConfig(epochs=20, starts="paper"))
    assert one.losses == paper.losses
    with pytest.raises(ValueError, match="starts"):
        FitConfig(starts="random")
