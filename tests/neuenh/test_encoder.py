"""The encoder (amortised starts): its contract, its training, its place in the bundle."""

from __future__ import annotations

import math
import pickle

import pytest
import torch

from neuenh.checkpoint import ENCODER, Bundle, BundleError
from neuenh.data.directions import Sampling
from neuenh.data.samples import Samples, sample_materials
from neuenh.data.synthetic import synthetic_ggx
from neuenh.encoder import EncoderConfig, MaterialEncoder
from neuenh.encoder_training import EncoderTrainConfig, FixedSets, MeasurementPools, start_losses, train_encoder
from neuenh.fit import LatentAdam, fit_materials
from neuenh.materials import MaterialTable
from neuenh.models import get_model

SMALL = EncoderConfig(width=24, depth=2, heads=2, head_hidden=48)


def _pools(materials) -> MeasurementPools:
    return MeasurementPools(sample_materials(materials, 1024, 0, sampling=Sampling(0.0, True)),
                            sample_materials(materials, 512, 0, sampling=Sampling(1.0, True)))


@pytest.fixture(scope="module")
def trained():
    """Plain GGX (no module: every material is its 12 analytical parameters) and an encoder trained
    for it in a few seconds on 24 of the paper's synthetic GGX materials; 8 others held out."""
    model = get_model("ggx")
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # tensors this small gain nothing from a second thread
    try:
        encoder, history = train_encoder(
            model, _pools(synthetic_ggx(24, seed=1)),
            EncoderTrainConfig(steps=80, materials_per_step=8, set_sizes=(1, 200), queries=64, lr=5e-3,
                               regression=0.0, eval_every=80),
            encoder_config=SMALL)
    finally:
        torch.set_num_threads(threads)
    return model, encoder, _pools(synthetic_ggx(8, seed=2))


def _sets(n_per_material: list[int], seed: int = 0) -> Samples:
    """Sets of the given sizes of as many synthetic GGX materials."""
    materials = synthetic_ggx(len(n_per_material), seed=seed)
    parts = [sample_materials([m], n, seed + i) for i, (m, n) in enumerate(zip(materials, n_per_material))]
    return Samples.concat(parts)


def test_beats_the_paper_start_on_held_out_materials(trained):
    model, encoder, held = trained
    sets = FixedSets.of(held, (1, 30, 300), queries=512, seed=3)
    for k in range(3):
        losses = start_losses(model, sets.block(k, len(held)), encoder, latent_mean=None)
        # the paper's start is the range means: far from a material; one sample already tells more
        assert losses["encoder"] < 0.8 * losses["paper"], (k, losses)
    few, many = (start_losses(model, sets.block(k, len(held)), encoder, None)["encoder"] for k in (0, 2))
    assert many < few  # more measurements, a better start


def test_an_encoded_start_fits_at_least_as_well(trained):
    """The encoder's start, fitted briefly, ends no worse than the paper's fitted as briefly."""
    model, encoder, held = trained
    measured = FixedSets.of(held.subset(range(4)), (100,), queries=1, seed=4).measured
    start = encoder.encode(measured)
    from_encoder = LatentAdam(epochs=8).fit(model, measured, start=start)
    from_paper = LatentAdam(epochs=8).fit(model, measured, start=MaterialTable(model.specs, measured.names, 27))
    assert from_encoder.loss <= from_paper.loss


@pytest.mark.parametrize("sizes", [[1], [1, 2, 7], [500, 1, 40]])
def test_any_set_size(trained, sizes):
    _, encoder, _ = trained
    samples = _sets(sizes)
    table = encoder.encode(samples)
    assert table.names == samples.names and len(table) == len(sizes)
    assert all(torch.isfinite(v).all() for v in table.values().values()) and torch.isfinite(table.latent).all()


def test_a_material_without_samples_gets_the_empty_sets_output(trained):
    _, encoder, _ = trained
    one = _sets([5])
    samples = Samples(one.wi, one.wo, one.f_r, one.material, (*one.names, "nothing"))
    table = encoder.encode(samples)
    assert torch.isfinite(table.latent).all() and torch.isfinite(table.values()["alpha_x"]).all()


def test_permutation_invariant(trained):
    """Shuffled rows give the same start: the pooled features agree to float32 rounding (the sums are
    float64), the outputs to what those differences can move through the head (its Lipschitz bound,
    LeakyReLU and tanh being 1-Lipschitz) plus the head's own float32 rounding (measured against a
    float64 evaluation of it)."""
    _, encoder, _ = trained
    samples = _sets([400, 3, 250])
    order = torch.randperm(len(samples), generator=torch.Generator().manual_seed(5))
    shuffled = samples.subset(order)
    with torch.no_grad():
        pooled, pooled_shuffled = encoder.pool(samples), encoder.pool(shuffled)
        ulp = torch.finfo(torch.float32).eps * pooled.abs()
        assert ((pooled - pooled_shuffled).abs() <= ulp).all()
        lipschitz = math.prod(torch.linalg.matrix_norm(layer.weight, ord=2).item()
                              for layer in encoder.head if isinstance(layer, torch.nn.Linear))
        head64 = [layer.double() if isinstance(layer, torch.nn.Linear) else layer for layer in
                  __import__("copy").deepcopy(encoder.head)]
        exact = torch.nn.Sequential(*head64)(pooled.double())
        rounding = (encoder.head(pooled).double() - exact).abs().max().item()
        bound = lipschitz * torch.linalg.vector_norm(pooled - pooled_shuffled, dim=1).max().item() + 2 * rounding
    a, b = encoder.encode(samples), encoder.encode(shuffled)
    for name in encoder.outputs:
        assert (a.raw[name] - b.raw[name]).abs().max().item() <= bound
    assert (a.latent - b.latent).abs().max().item() <= bound


def test_finite_on_extreme_values_and_directions(trained):
    """f_r of 0 and 1e6, grazing and below-horizon directions, exactly opposite ones: finite
    parameters and finite gradients (the training path)."""
    _, encoder, _ = trained
    z = 1e-7
    wi = torch.tensor([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [math.sqrt(1 - z * z), 0.0, z], [0.0, 0.6, -0.8],
                       [0.0, 0.0, 1.0], [0.6, 0.0, 0.8]])
    wo = torch.tensor([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [-math.sqrt(1 - z * z), 0.0, z], [0.0, -0.6, 0.8],
                       [0.0, 0.0, 1.0], [-0.6, 0.0, 0.8]])
    for values in (0.0, 1e6, 3.4e38):
        f_r = torch.full((len(wi), 3), values)
        f_r[-1] = -1.0  # a noisy measurement below zero counts as 0
        samples = Samples(wi, wo, f_r, torch.tensor([0, 0, 0, 1, 1, 1]), ("a", "b"))
        encoder.zero_grad()
        raw, latent = encoder(samples)
        (sum(v.sum() for v in raw.values()) + latent.sum()).backward()
        assert all(torch.isfinite(v).all() for v in raw.values()) and torch.isfinite(latent).all(), values
        assert all(torch.isfinite(p.grad).all() for p in encoder.parameters() if p.grad is not None), values


@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_non_finite_measurements_are_refused(trained, bad):
    _, encoder, _ = trained
    samples = _sets([4])
    samples.f_r[2, 1] = bad
    with pytest.raises(ValueError, match=r"non-finite f_r \(rows \[2\]\)"):
        encoder.encode(samples)


def test_bundle_round_trip_without_pickle(trained, tmp_path, monkeypatch):
    model, encoder, _ = trained
    bundle = Bundle(model, MaterialTable(model.specs, ["m"], model.latent_dim), encoder=encoder)
    encoder.record = {"note": "test"}
    bundle.save(tmp_path / "b")
    blob = bundle.to_bytes()

    def refuse(*_a, **_k):
        raise AssertionError("a bundle was unpickled")

    monkeypatch.setattr(pickle, "loads", refuse)
    monkeypatch.setattr(pickle, "load", refuse)
    monkeypatch.setattr(torch, "load", refuse)
    samples = _sets([50, 7])
    for loaded in (Bundle.load(tmp_path / "b"), Bundle.from_bytes(blob)):
        assert loaded.encoder is not None and loaded.encoder.record == {"note": "test"}
        assert loaded.describe()["encoder"]["outputs"] == list(encoder.outputs)
        a, b = encoder.encode(samples), loaded.encoder.encode(samples)
        assert all(torch.equal(a.raw[k], b.raw[k]) for k in a.raw) and torch.equal(a.latent, b.latent)


def test_a_changed_encoder_file_is_refused(trained, tmp_path):
    model, encoder, _ = trained
    Bundle(model, None, encoder=encoder).save(tmp_path)
    other = MaterialEncoder(model.specs, encoder.outputs, model.latent_dim, SMALL, seed=9)
    from safetensors.torch import save_file

    save_file(other.tensors(), tmp_path / ENCODER)
    with pytest.raises(BundleError, match="encoder.safetensors: does not match model.json"):
        Bundle.load(tmp_path)


def test_a_bundle_without_an_encoder_loads_and_fits_as_before(trained, tmp_path):
    model, encoder, _ = trained
    Bundle(model, None, encoder=encoder).save(tmp_path)
    Bundle(model, None).save(tmp_path)  # saved again without: the file goes, model.json names none
    assert not (tmp_path / ENCODER).exists()
    loaded = Bundle.load(tmp_path)
    assert loaded.encoder is None and "encoder" not in loaded.describe()
    samples = _sets([200])
    result = fit_materials(loaded.model, samples, LatentAdam(epochs=5))
    assert math.isfinite(result.loss)


def test_outputs_must_be_parameters_of_the_model():
    model = get_model("ggx")
    with pytest.raises(ValueError, match=r"encoder outputs \['sheen'\]"):
        MaterialEncoder(model.specs, ["alpha_x", "sheen"], 27)


def test_pools_refuse_rgl():
    from neuenh.data.sources import RGLSource

    with pytest.raises(ValueError, match="RGL is the validation set"):
        MeasurementPools.from_sources([RGLSource(source="rgl", paths=["x.bsdf"])])


def test_the_encoder_alone_as_a_study_contender(trained):
    """The report's "encoder alone" row: the model with the encoded parameters, no fitting."""
    from neuenh.study.contenders import EncodedContender

    model, encoder, held = trained
    samples = _sets([300])
    fitted = EncodedContender("enhanced-encoder", "encoder alone", "enhanced", model, encoder).fit(samples)
    table = encoder.encode(samples)
    wi, wo = samples.wi[:50], samples.wo[:50]
    expected = model.evaluate(wi, wo, table.as_params(0))
    torch.testing.assert_close(fitted.brdf(wi, wo).float(), expected.float().clamp_min(0), rtol=1e-5, atol=1e-6)
    assert fitted.params_per_material == model.n_material_params() and math.isfinite(fitted.fit_loss)
