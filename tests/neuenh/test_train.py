import copy
import dataclasses
import os
import shutil
import warnings

import numpy as np
import pytest
import torch

from neuenh.checkpoint import Bundle
from neuenh.data.samples import Samples
from neuenh.train import STEP_ROWS, TrainConfig, backward_in_slices, batch_loss, log_l1, train_candidate
from neuenh.data.samples import TrainingData
from ggx_states import ALTERNATIVES_STATE, PAPER_STATE

QUICK = TrainConfig(epochs=3, batch_size=2000)


def test_loss_is_the_papers_log_l1():
    g = np.random.default_rng(0)
    wi = g.normal(size=(500, 3))
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    target, pred = g.uniform(0, 50, (500, 3)), g.uniform(0, 50, (500, 3))
    cos = np.clip(wi[:, 2:3], 0, None)
    expected = np.abs(np.log(1 + target * cos) - np.log(1 + pred * cos)).mean(axis=1)
    got = log_l1(*(torch.as_tensor(a) for a in (pred, target, wi)))
    assert np.allclose(got.numpy(), expected, rtol=1e-12)


def test_loss_is_finite_with_a_gradient_for_negative_predictions():
    pred = torch.tensor([[-5.0, -0.5, 2.0]], requires_grad=True)
    loss = log_l1(pred, torch.ones(1, 3), torch.tensor([[0.0, 0.0, 1.0]])).sum()
    loss.backward()
    assert torch.isfinite(loss) and torch.isfinite(pred.grad).all()
    assert (pred.grad[0, :2] < 0).all()  # descent raises the negative predictions


def test_training_is_a_pure_function_of_its_inputs(small_data):
    parent = Bundle.initial("ggx", small_data.names)
    a = train_candidate(parent, PAPER_STATE, small_data, QUICK, seed=5)
    b = train_candidate(parent, PAPER_STATE, small_data, QUICK, seed=5)
    assert (a.train_loss, a.val_loss, a.epoch_losses) == (b.train_loss, b.val_loss, b.epoch_losses)
    for key, value in a.bundle.model.neural.state_dict().items():
        assert torch.equal(value, b.bundle.model.neural.state_dict()[key])
    c = train_candidate(parent, PAPER_STATE, small_data, QUICK, seed=6)
    assert c.val_loss != a.val_loss


def test_modules_latent_and_analytical_parameters_train_jointly(small_data):
    parent = Bundle.initial("ggx", small_data.names)
    before = copy.deepcopy(parent)
    result = train_candidate(parent, PAPER_STATE, small_data, QUICK, seed=0)
    assert result.ok and result.epochs == 3 and result.state == PAPER_STATE
    trained = result.bundle
    assert not torch.equal(trained.materials.latent, before.materials.latent)
    for name in ("rho_d", "alpha_x", "f0"):
        assert not torch.equal(trained.materials.raw[name], before.materials.raw[name])
    fresh = parent.model.enhance(PAPER_STATE, seed=0)
    assert not torch.equal(trained.model.neural["F"].layers[0].weight, fresh.neural["F"].layers[0].weight)
    # The parent is untouched: candidates train in isolation.
    assert torch.equal(parent.materials.latent, before.materials.latent)


def test_training_lowers_the_validation_loss(small_data):
    parent = Bundle.initial("ggx", small_data.names)
    untrained = train_candidate(parent, "0" * 11, small_data, TrainConfig(epochs=0), seed=0)
    config = TrainConfig(epochs=10, batch_size=1000, lr=1e-2)
    trained = train_candidate(parent, "0" * 11, small_data, config, seed=0)
    assert trained.val_loss < 0.8 * untrained.val_loss


def test_candidates_continue_from_the_parents_training(small_data):
    parent = Bundle.initial("ggx", small_data.names)
    round1 = train_candidate(parent, "00010000000", small_data, QUICK, seed=0).bundle
    stay = train_candidate(round1, "00010000000", small_data, TrainConfig(epochs=0), seed=1)
    assert stay.val_loss == pytest.approx(round1.metrics["val_loss"], rel=1e-6)


def test_a_diverging_candidate_is_reported_not_raised(small_data):
    bad_f = small_data.train.f_r.clone()
    bad_f[0] = float("nan")
    t = small_data.train
    data = TrainingData(Samples(t.wi, t.wo, bad_f, t.material, t.names), small_data.val)
    result = train_candidate(Bundle.initial("ggx", data.names), PAPER_STATE, data, QUICK, seed=0)
    assert not result.ok and "epoch 1" in result.error


def test_parent_materials_must_match_the_data(small_data):
    with pytest.raises(ValueError, match="parent bundle's materials"):
        train_candidate(Bundle.initial("ggx", ["other"]), PAPER_STATE, small_data, QUICK, seed=0)


def test_lr_final_decays_the_learning_rate_by_a_cosine():
    """``lr_final == lr`` is the constant lr bit for bit; a lower ``lr_final`` changes only epochs
    after the first (the cosine steps after each epoch); ``lr_final > lr`` is refused."""
    import dataclasses

    from neuenh.data.samples import sample_materials
    from neuenh.data.synthetic import synthetic_zoo

    materials = synthetic_zoo(2, seed=2)
    data = TrainingData(sample_materials(materials, 600, seed=0), sample_materials(materials, 200, seed=1))
    parent = Bundle.initial("ggx", data.names)
    constant = TrainConfig(epochs=3, lr=5e-3, batch_size=256)

    def run(config):
        return train_candidate(parent, "00010000000", data, config, seed=7)

    assert run(constant).epoch_losses == run(dataclasses.replace(constant, lr_final=5e-3)).epoch_losses
    decayed = run(dataclasses.replace(constant, lr_final=5e-5)).epoch_losses
    steady = run(constant).epoch_losses
    assert decayed[0] == steady[0] and decayed[1:] != steady[1:]
    with pytest.raises(ValueError, match="invalid training config"):
        TrainConfig(lr=1e-3, lr_final=2e-3)


def test_a_latent_prior_adds_each_samples_share_of_its_materials_squared_distance_from_the_start(small_data):
    """``batch_loss(..., latent_prior=w)``: the batch's mean log-L1 plus w times the mean over its samples
    of their material's mean squared distance of the code from 0.5 (numpy); its gradient on a code is
    the data term's plus w * 2 (z - 0.5) / latent_dim * (the material's share of the batch). Without
    modules reading the code, no prior."""
    bundle = Bundle.initial("ggx", small_data.names)
    model = bundle.model.enhance(PAPER_STATE, seed=0)
    materials = bundle.materials
    g = np.random.default_rng(3)
    with torch.no_grad():
        materials.latent.copy_(torch.as_tensor(g.uniform(-1, 2, tuple(materials.latent.shape)), dtype=torch.float32))
    train = small_data.train
    batch = (train.wi[:900], train.wo[:900], train.f_r[:900], train.material[:900])
    z, material = materials.latent.detach().double().numpy(), batch[3].numpy()
    expected_prior = ((z - 0.5) ** 2).mean(axis=1)[material].mean()
    share = np.bincount(material, minlength=len(z)) / len(material)
    expected_grad = 2 * (z - 0.5) / z.shape[1] * share[:, None]

    def loss_and_code_gradient(weight):
        materials.latent.grad = None
        loss = batch_loss(model, materials, latent_prior=weight)(*batch)
        loss.backward()
        return float(loss.detach()), materials.latent.grad.double().numpy()

    data, data_grad = loss_and_code_gradient(0.0)
    with_prior, prior_grad = loss_and_code_gradient(0.25)
    eps = torch.finfo(torch.float32).eps
    assert with_prior - data == pytest.approx(0.25 * expected_prior, rel=100 * eps, abs=100 * eps * data)
    assert np.allclose(prior_grad - data_grad, 0.25 * expected_grad, rtol=1e-4, atol=1e-4 * np.abs(expected_grad).max())
    analytical = bundle.model.enhance("0" * 11, seed=0)
    assert batch_loss(analytical, materials, latent_prior=0.25)(*batch) == batch_loss(analytical, materials)(*batch)


def test_a_latent_prior_keeps_the_codes_nearer_the_start_and_is_recorded(small_data):
    """Trained with a strong prior, the codes end nearer 0.5 than without one; the bundle's training
    record names the prior only when there is one, and a negative or infinite weight is refused."""
    parent = Bundle.initial("ggx", small_data.names)
    config = TrainConfig(epochs=3, batch_size=500, lr=1e-2)
    free = train_candidate(parent, PAPER_STATE, small_data, config, seed=1).bundle
    held = train_candidate(parent, PAPER_STATE, small_data, dataclasses.replace(config, latent_prior=10.0), seed=1).bundle
    spread = lambda bundle: float((bundle.materials.latent - 0.5).square().mean())
    assert spread(held) < 0.5 * spread(free)
    assert held.training["latent_prior"] == 10.0 and "latent_prior" not in free.training
    for weight in (-1e-3, float("inf")):
        with pytest.raises(ValueError, match="invalid training config"):
            TrainConfig(latent_prior=weight)


def _gradient(model, materials, batch, rows):
    """The flattened gradient (float64) of ``batch``'s mean loss, taken ``rows`` rows at a time, and that loss."""
    params = [*model.neural.parameters(), *materials.parameters()]
    for p in params:
        p.grad = None
    loss = backward_in_slices(batch_loss(model, materials), *batch, rows=rows)
    return torch.cat([p.grad.flatten().double() for p in params]), loss


@pytest.mark.parametrize("n, rows", [(3000, 1000), (3000, 700), (500, 1000)])
def test_a_batch_taken_in_slices_has_the_batch_means_gradient(small_data, n, rows):
    """``backward_in_slices``: whatever the slicing (a remainder included), the loss is the batch's mean
    and the gradient its gradient. Both are checked against the same step in float64: the sliced one's
    error is no more than twice the one-pass float32 error measured here (the reference path's own
    rounding: slicing only reorders the sums). A batch of at most ``rows`` is one pass, bit for bit."""
    bundle = Bundle.initial("ggx", small_data.names)
    model = bundle.model.enhance(PAPER_STATE, seed=0)
    train = small_data.train
    batch = (train.wi[:n], train.wo[:n], train.f_r[:n] * 3, train.material[:n])  # * 3: a gradient far from zero
    exact_model, exact_materials = copy.deepcopy(model).double(), copy.deepcopy(bundle.materials)
    for p in exact_materials.parameters():
        p.data = p.data.double()
    exact, exact_loss = _gradient(exact_model, exact_materials, [x.double() if x.is_floating_point() else x
                                                                 for x in batch], rows=n)
    whole, whole_loss = _gradient(model, bundle.materials, batch, rows=n)
    sliced, sliced_loss = _gradient(model, bundle.materials, batch, rows=rows)
    if n <= rows:
        assert torch.equal(sliced, whole) and sliced_loss == whole_loss
    eps = torch.finfo(torch.float32).eps
    assert abs(sliced_loss - exact_loss) <= n * eps * exact_loss  # a sum of n positive terms
    one_pass_error = (whole - exact).norm()
    assert 0 < one_pass_error < 1e-3 * exact.norm()
    assert (sliced - exact).norm() <= 2 * one_pass_error


def test_a_batch_larger_than_a_slice_trains_on_its_whole_mean(small_data):
    """``train_candidate`` takes a batch over ``STEP_ROWS`` rows in slices: its first epoch's loss (one
    batch, measured before the update) is still the whole batch's mean loss."""
    train = small_data.train
    assert len(train) > STEP_ROWS, "a batch that needs two slices"
    bundle = Bundle.initial("ggx", small_data.names)
    config = TrainConfig(epochs=1, batch_size=len(train))
    result = train_candidate(bundle, PAPER_STATE, small_data, config, seed=0)
    model = bundle.model.enhance(PAPER_STATE, seed=0)
    with torch.no_grad():
        whole = float(batch_loss(model, bundle.materials)(train.wi, train.wo, train.f_r, train.material))
    assert result.epoch_losses[0] == pytest.approx(whole, rel=len(train) * torch.finfo(torch.float32).eps)


@pytest.mark.skipif(shutil.which(os.environ.get("CXX", "g++")) is None,
                    reason="torch.compile needs a C++ compiler (g++; `make install` installs it as root)")
def test_a_compiled_training_step_trains_the_same_candidate_deterministically(small_data):
    """``TrainConfig(compile=True)`` (torch.compile of the step): the same inputs give bit-identical
    losses run to run, and the candidate matches the eager one up to float rounding. One module (of
    D) and batches of one size keep it to one compiled graph per run: compiling is what this costs."""
    parent = Bundle.initial("ggx", small_data.names)
    state = "00100000000"
    config = TrainConfig(epochs=2, batch_size=len(small_data.train) // 2)
    assert len(small_data.train) % 2 == 0, "two batches of one size"
    eager = train_candidate(parent, state, small_data, config, seed=5)
    compiled = [train_candidate(parent, state, small_data, dataclasses.replace(config, compile=True), seed=5)
                for _ in range(2)]
    assert compiled[0].epoch_losses == compiled[1].epoch_losses and compiled[0].val_loss == compiled[1].val_loss
    assert compiled[0].epoch_losses == pytest.approx(eager.epoch_losses, rel=1e-4)
    assert compiled[0].val_loss == pytest.approx(eager.val_loss, rel=1e-4)
    assert compiled[0].bundle.training["compile"] is True


@pytest.mark.parametrize("model_name, alternatives, state", [
    *((name, False, None) for name in ("ggx", "cook_torrance", "ward", "blinn_phong", "ggx_residual")),
    ("ggx", False, PAPER_STATE), ("ggx", True, ALTERNATIVES_STATE)])
def test_the_training_step_traces_into_one_graph(model_name, alternatives, state):
    """torch.compile sees the whole step (the analytical formulas with the tilted, rotated shading
    frame; modules; alternative terms) as one graph: each graph break splits the compiled step, and
    one in the shading frame held it at 1.6-1.8x the eager step instead of 2.1x. Dynamo alone
    traces (no kernels compiled), so this costs a second, not a compile."""
    bundle = Bundle.initial(model_name, ["a", "b", "c"], alternatives=alternatives)
    model = bundle.model.enhance(state or "0" * len(bundle.model.graph.positions), seed=0)
    n = 64
    wi = torch.nn.functional.normalize(torch.randn(n, 3, generator=torch.Generator().manual_seed(0)), dim=1).abs()
    wo = torch.nn.functional.normalize(torch.randn(n, 3, generator=torch.Generator().manual_seed(1)), dim=1).abs()
    torch._dynamo.reset()
    explained = torch._dynamo.explain(batch_loss(model, bundle.materials))(wi, wo, torch.rand(n, 3), torch.arange(n) % 3)
    assert (explained.graph_count, explained.graph_break_count) == (1, 0), explained.break_reasons


def test_bfloat16_precision_runs_the_products_in_bfloat16_and_keeps_loss_and_gradients_float32(small_data, monkeypatch):
    """``TrainConfig(precision="bfloat16")``: every matrix product of the step (forward and backward)
    reads bfloat16 operands (float32 ones by default); the loss, the parameters and their gradients
    stay float32, and a candidate records the precision it trained at; on a CPU without bfloat16
    arithmetic (emulated products, several times slower) training says so."""
    from torch.utils._python_dispatch import TorchDispatchMode

    products = {torch.ops.aten.mm.default, torch.ops.aten.addmm.default}

    class Dtypes(TorchDispatchMode):
        def __init__(self):
            super().__init__()
            self.products: set[torch.dtype] = set()  # the products' operand dtypes

        def __torch_dispatch__(self, func, types, args=(), kwargs=None):
            if func in products:
                self.products |= {a.dtype for a in args if isinstance(a, torch.Tensor)}
            return func(*args, **(kwargs or {}))

    bundle = Bundle.initial("ggx", small_data.names)
    model = bundle.model.enhance(PAPER_STATE, seed=0)
    train = small_data.train
    batch = (train.wi[:256], train.wo[:256], train.f_r[:256], train.material[:256])
    for precision, product_dtypes in (("float32", {torch.float32}), ("bfloat16", {torch.bfloat16})):
        with Dtypes() as mode:
            loss = batch_loss(model, bundle.materials, precision)(*batch)
            loss.backward()
        assert mode.products == product_dtypes, precision
        assert loss.dtype == torch.float32 and torch.isfinite(loss)
        grads = [p.grad for p in model.neural.parameters()]
        assert all(g.dtype == torch.float32 and torch.isfinite(g).all() for g in grads)
        model.neural.zero_grad()
    monkeypatch.setattr("neuenh.train.native_bfloat16", lambda: True)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning where the CPU has bfloat16 arithmetic
        result = train_candidate(bundle, PAPER_STATE, small_data, dataclasses.replace(QUICK, precision="bfloat16"), seed=5)
    assert result.ok and result.bundle.training["precision"] == "bfloat16"
    monkeypatch.setattr("neuenh.train.native_bfloat16", lambda: False)
    with pytest.warns(RuntimeWarning, match="without bfloat16 arithmetic"):
        train_candidate(bundle, PAPER_STATE, small_data, dataclasses.replace(QUICK, precision="bfloat16", epochs=0), seed=5)
    assert "precision" not in train_candidate(bundle, PAPER_STATE, small_data, QUICK, seed=5).bundle.training
    with pytest.raises(ValueError, match="invalid training config"):
        TrainConfig(precision="float16")
