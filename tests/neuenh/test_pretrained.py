"""Models by name: analytical, shipped (models/ or NEUENH_MODELS_DIR), bundle folders."""

from pathlib import Path

import pytest
import torch

from neuenh.checkpoint import Bundle
from neuenh.pretrained import load_model, shipped_models

REPO_MODELS = Path(__file__).resolve().parents[2] / "models"


def test_an_analytical_name_has_no_training_materials():
    model, trained = load_model("cook_torrance")
    assert model.name == "cook_torrance" and model.state == "0" * len(model.positions) and trained is None


def test_a_bundle_folder_and_a_shipped_name_load_the_same_bundle(tmp_path, monkeypatch):
    bundle = Bundle.initial("ggx", ["a", "b"])
    bundle.model = bundle.model.enhance("00010000000", seed=1)
    bundle.save(tmp_path / "mine")
    monkeypatch.setenv("NEUENH_MODELS_DIR", str(tmp_path))
    assert shipped_models()["mine"] == tmp_path / "mine"
    for spec in ("mine", str(tmp_path / "mine")):
        model, trained = load_model(spec)
        assert model.state == "00010000000" and trained.names == ("a", "b")


def test_an_installed_package_finds_its_package_data_and_no_stranger_models_folder(tmp_path, monkeypatch):
    """Installed, ``neuenh`` sits in site-packages: its models are its package data
    (``neuenh/shipped_models``), never a ``models/`` folder beside it that another distribution put there."""
    import neuenh.pretrained as pretrained

    site = tmp_path / "site-packages"
    Bundle.initial("ggx", ["a"]).save(site / "models" / "stranger")
    (site / "neuenh").mkdir()
    monkeypatch.setattr(pretrained, "_PACKAGE", site / "neuenh")
    monkeypatch.delenv("NEUENH_MODELS_DIR", raising=False)
    assert shipped_models() == {}
    Bundle.initial("ggx", ["a"]).save(site / "neuenh" / "shipped_models" / "mine")
    assert shipped_models() == {"mine": site / "neuenh" / "shipped_models" / "mine"}
    monkeypatch.setenv("NEUENH_MODELS_DIR", str(site / "models"))  # named: found first
    assert list(shipped_models()) == ["mine", "stranger"]


def test_an_unknown_name_lists_what_exists(monkeypatch, tmp_path):
    monkeypatch.setenv("NEUENH_MODELS_DIR", str(tmp_path))
    with pytest.raises(ValueError, match=r"neither an analytical model \(ggx, .*\), a shipped model"):
        load_model("enhanced-ggz")


@pytest.mark.skipif(not (REPO_MODELS / "enhanced-ggx" / "model.json").exists(), reason="no shipped model in this tree")
def test_the_shipped_enhanced_ggx_is_small_enhanced_and_trained_without_rgl():
    from neuenh.pretrained import rungs

    model, trained = load_model("enhanced-ggx")
    assert model.name == "ggx" and model.has_modules and model.latent_dim == 27
    size = sum(p.stat().st_size for p in (REPO_MODELS / "enhanced-ggx").iterdir())
    assert size < 300_000  # the model, its 260 training materials, its rungs and its search's history
    assert len(trained) == 260 and not any("rgb" in name for name in trained.names)  # never RGL
    ladder = rungs("enhanced-ggx")
    assert len(ladder) >= 2 and ladder[-1].state == model.state  # the search's winners, the model last
    assert [r.round for r in ladder] == sorted(r.round for r in ladder)


def test_rungs_of_a_model_are_its_search_winners_or_itself(tmp_path, monkeypatch):
    from neuenh.checkpoint import Rung
    from neuenh.pretrained import rungs

    bundle = Bundle.initial("ggx", ["a", "b"])
    plain = Bundle(bundle.model, bundle.materials)
    bundle.model = bundle.model.enhance("00000100000", seed=1)
    bundle.metrics = {"val_loss": 0.02}
    bundle.save(tmp_path / "bare")
    [itself] = rungs(str(tmp_path / "bare"))
    assert (itself.round, itself.state, itself.val_loss) == (-1, "00000100000", 0.02)
    assert torch.equal(itself.latent_codes, torch.full((2, 27), 0.5))  # the training materials' codes
    bundle.rungs = [Rung.of(0, 0.04, plain), Rung.of(2, 0.02, bundle)]
    bundle.save(tmp_path / "laddered")
    monkeypatch.setenv("NEUENH_MODELS_DIR", str(tmp_path))
    assert [(r.round, r.state) for r in rungs("laddered")] == [(0, "00000000000"), (2, "00000100000")]
    # The model itself, last, starts its fits from the bundle's own training codes even where its rung
    # kept fewer (a bundle written before stop 57 kept their mean alone).
    with torch.no_grad():
        bundle.materials.latent[1] = 2.0
    bundle.rungs = [Rung.of(0, 0.04, plain), Rung(2, 0.02, bundle.model, bundle.materials.mean_latent()[None])]
    bundle.save(tmp_path / "mean-only")
    assert torch.equal(rungs("mean-only")[-1].latent_codes, bundle.materials.latent_codes())
    with pytest.raises(ValueError, match="neither a shipped model"):
        rungs("ggx")
