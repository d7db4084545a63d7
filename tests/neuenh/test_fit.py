"""neuenh.fit: the protocols' shared contract (one class, every protocol), the kernel against
independent references, the row layout, and what each protocol promises of its own."""

import copy
import math
import re

import numpy as np
import pytest
import torch

from neuenh.data.directions import sample_directions
from neuenh.data.samples import sample_materials
from neuenh.data.synthetic import synthetic_ggx, synthetic_zoo
from neuenh.fit import (SURROGATE_EPS, Adaptive, FitOptions, LatentAdam, PaperRMSProp, PlainLBFGS, fit_materials,
                        per_material_loss)
from neuenh.data.samples import Samples
from neuenh.fit.capacity import capacity_space, gap_errors, simplest_within
from neuenh.fit.jit import available as jit_available
from neuenh.fit.kernel import LayerCorrection, RowKernel, RowSpace
from neuenh.fit.layout import compacted, fold_masks, layout_rows, padded
from neuenh.fit.optim import Adam, adam_rows, evaluate_rows, lbfgs_rows
from neuenh.fit.parallel import fit_in_processes, shares
from neuenh.fit.run import blocks
from neuenh.fit.protocols import SCREEN_SLOTS, Rows
from neuenh.materials import MaterialTable
from neuenh.models import get_model
from neuenh.pretrained import load_model
from neuenh.study.heldout import heldout_log_l1, predict_f_r
from neuenh.train import log_l1
from ggx_states import PAPER_STATE
from random_tables import random_table

FLOAT32_EPS = torch.finfo(torch.float32).eps


@pytest.fixture(scope="module")
def clean_ggx():
    (material,) = synthetic_ggx(1, seed=21, noise_sigma=0.0)
    return material, sample_materials([material], 5000, seed=0)


@pytest.fixture(scope="module")
def two_zoo_materials():
    return sample_materials(synthetic_zoo(2, seed=5), 600, seed=1)


@pytest.fixture(scope="module")
def enhanced():
    return get_model("ggx", state="00010001000", seed=3)  # F and the operator S*D*F neural


# -- the contract every protocol keeps -----------------------------------------------------------
PROTOCOLS = {
    "paper": lambda: PaperRMSProp(epochs=8),
    "plain": lambda: PlainLBFGS(iterations=8, warmup_epochs=4),
    "latent": lambda: LatentAdam(epochs=9),
    "latent-coarse": lambda: LatentAdam(epochs=9, coarse_slots=200),  # its starts race on 200 of the 600 samples
    "adaptive": lambda: Adaptive(latent_epochs=6, correction_epochs=4, lbfgs_iterations=5, priors=(1e-2,), folds=2),
}


@pytest.mark.parametrize("name", PROTOCOLS)
class TestProtocolContract:
    def test_module_weights_stay_frozen_and_losses_are_the_returned_parameters(self, name, enhanced,
                                                                              two_zoo_materials):
        samples = two_zoo_materials
        before = {k: v.clone() for k, v in enhanced.state_dict().items()}
        result = PROTOCOLS[name]().fit(enhanced, samples, seed=1)
        for key, value in enhanced.state_dict().items():
            assert torch.equal(value, before[key])
        assert all(p.requires_grad for p in enhanced.parameters())
        assert result.materials.names == samples.names and result.protocol["name"] == name.split("-")[0]
        assert result.losses_on(enhanced, samples) == pytest.approx(result.losses, rel=1e-4)

    def test_a_material_does_not_depend_on_the_others_fitted_beside_it(self, name, enhanced, two_zoo_materials):
        samples = two_zoo_materials
        both = PROTOCOLS[name]().fit(enhanced, samples, seed=1)
        one = samples.of_material(0)
        one = type(one)(one.wi, one.wo, one.f_r, torch.zeros(len(one), dtype=torch.long), samples.names[:1])
        alone = PROTOCOLS[name]().fit(enhanced, one, seed=1)
        assert alone.losses[0] == pytest.approx(both.losses[0], rel=0.05)

    def test_a_start_is_where_the_fit_starts(self, name, enhanced, two_zoo_materials):
        samples = two_zoo_materials
        fitted = LatentAdam(epochs=30).fit(enhanced, samples, seed=0).materials
        restarted = PROTOCOLS[name]().fit(enhanced, samples, start=fitted, seed=0)
        assert max(restarted.losses) < 1.5 * max(per_material_loss(enhanced, fitted, samples))
        with pytest.raises(ValueError, match="start"):
            PROTOCOLS[name]().fit(enhanced, samples, start=fitted.subset([0]))


# -- the kernel against independent references ---------------------------------------------------
def test_kernel_losses_and_corrections_equal_the_model_with_corrected_weights(enhanced, two_zoo_materials):
    """Each row's loss (mean and per sample) is the model's own log-L1 with the row's corrections
    added to its weights (``torch.func.functional_call``, evaluated per material), also when evaluated
    in slot chunks, and the gradient is the float64 kernel's within float32 rounding."""
    samples = two_zoo_materials
    table = random_table(enhanced, samples.names, 0)
    corrections = [LayerCorrection(p, i, None if i % 2 else 2) for p in enhanced.neural for i in range(4)]
    space = RowSpace(enhanced, corrections)
    x = space.from_table(table, seed=1)
    x[:, space.base_dim:] += 0.05 * torch.randn(x[:, space.base_dim:].shape, generator=torch.Generator().manual_seed(2))
    wi, wo, f_r, valid = padded(samples)
    layout = layout_rows(wi, wo, f_r, torch.arange(2), valid, torch.zeros_like(valid))
    losses = RowKernel(enhanced, space)(x, layout)
    chunked = evaluate_rows(RowKernel(enhanced, space), x, layout, batch_slots=97)
    for i in range(2):
        rows = samples.of_material(i)
        dense = space.dense_corrections(x[i])
        weights = {f"neural.{k}": w + dense[k] for k, w in enhanced.neural.state_dict().items() if k in dense}
        values = {k: v[i : i + 1].expand(len(rows), -1) for k, v in table.values().items()}
        pred = torch.func.functional_call(enhanced, weights, (rows.wi, rows.wo, values,
                                                               table.latent[i : i + 1].expand(len(rows), -1)))
        per_sample = log_l1(pred, rows.f_r, rows.wi).detach().double()
        assert float(losses.train[i]) == pytest.approx(float(per_sample.mean()), rel=1e-5)
        mine = losses.per_sample[i][valid[i]]  # the samples in the padded rows' shuffled order
        assert torch.allclose(mine.sort().values, per_sample.sort().values, rtol=1e-5, atol=1e-7)
    # the chunks: the same losses up to float32 rounding (matrix products blocked differently)
    assert torch.allclose(chunked.per_sample, losses.per_sample, rtol=1e-5, atol=1e-7)
    assert torch.allclose(chunked.train, losses.train, rtol=1e-5)
    double = copy.deepcopy(enhanced).double()
    layout64 = layout_rows(wi.double(), wo.double(), f_r.double(), torch.arange(2), valid, torch.zeros_like(valid))
    reference = RowKernel(double, RowSpace(double, corrections))(x.double(), layout64).grad
    error = (losses.grad.double() - reference).abs().max()
    assert error <= 1e-3 * reference.abs().max()  # float32 through ~10 layers of a few dozen terms


@pytest.mark.parametrize("surrogate_eps", [None, 1e-2])
def test_a_kernel_over_slot_chunks_has_the_objective_and_gradient_of_one_pass(enhanced, two_zoo_materials,
                                                                               surrogate_eps):
    """``chunk_slots``: a layout wider than it is evaluated a chunk at a time, each chunk's share of
    the objective differentiated apart and the prior once. In float64 (a copy of the model) every
    output equals one pass's to the rounding of summing ~600 terms in another order (~1e-13)."""
    double = copy.deepcopy(enhanced).double()
    corrections = [LayerCorrection(p, i, None if i % 2 else 2) for p in double.neural for i in range(4)]
    space = RowSpace(double, corrections)
    samples = two_zoo_materials
    x = space.from_table(random_table(double, samples.names, 0), seed=1).double()
    x[:, space.base_dim:] += 0.05 * torch.randn(x[:, space.base_dim:].shape, generator=torch.Generator().manual_seed(2),
                                                dtype=torch.float64)
    wi, wo, f_r, valid = padded(samples)
    train, val = valid.clone(), torch.zeros_like(valid)
    train[:, ::5], val[:, ::5] = False, valid[:, ::5]  # a fifth of each row held out
    layout = layout_rows(wi.double(), wo.double(), f_r.double(), torch.arange(2), train, val)
    prior = torch.tensor([1e-2, 1e-3], dtype=torch.float64)
    kernel = RowKernel(double, space)
    whole = kernel(x, layout, prior_strength=prior, surrogate_eps=surrogate_eps)
    chunked = kernel(x, layout, prior_strength=prior, surrogate_eps=surrogate_eps, chunk_slots=97)
    assert layout.slots > 97 * 6
    for name in ("train", "val", "objective", "grad", "per_sample"):
        assert torch.allclose(getattr(chunked, name), getattr(whole, name), rtol=1e-11, atol=1e-14), name
    assert kernel(x, layout, grad=False, chunk_slots=97).grad is None
    with pytest.raises(ValueError, match="chunk_slots must be at least 1"):
        kernel(x, layout, chunk_slots=0)


def test_a_rows_gradient_does_not_depend_on_the_rows_beside_it(enhanced, two_zoo_materials):
    """Row 0 alone and stacked with another row: the same loss and gradient up to the float32
    rounding of the stacked products (bounded by the float32 kernel's distance to float64)."""
    samples = two_zoo_materials
    space = RowSpace(enhanced, [LayerCorrection(p, 3) for p in enhanced.neural])
    table = random_table(enhanced, samples.names, 4)
    x = space.from_table(table)
    wi, wo, f_r, valid = padded(samples)
    stacked = layout_rows(wi, wo, f_r, torch.tensor([0, 1]), valid, torch.zeros_like(valid))
    kernel = RowKernel(enhanced, space)
    both = kernel(x, stacked)
    alone = kernel(x[:1], stacked.select([0]))
    double = copy.deepcopy(enhanced).double()
    layout64 = layout_rows(wi.double(), wo.double(), f_r.double(), torch.tensor([0]), valid[:1],
                           torch.zeros_like(valid[:1]))
    exact = RowKernel(double, RowSpace(double, space.corrections))(x[:1].double(), layout64).grad
    rounding = (alone.grad.double() - exact).abs().max()
    assert (both.grad[:1] - alone.grad).abs().max() <= 4 * rounding + 8 * FLOAT32_EPS * exact.abs().max()
    assert float(both.train[0]) == pytest.approx(float(alone.train[0]), rel=1e-5)


@pytest.mark.parametrize("state", ["00000000000", PAPER_STATE, "00010001000"])
def test_kernel_is_finite_at_grazing_below_horizon_and_tiny_roughness(state):
    """Directions at 89.99 degrees, below either horizon and exactly at the horizon, roughness at
    its lower bound, and corrections in every layer: finite losses and finite gradients."""
    model = get_model("ggx", state=state, seed=0)
    corrections = [LayerCorrection(p, i, 2) for p in model.neural for i in range(4)]
    space = RowSpace(model, corrections)
    graze = torch.tensor([0.99999998, 0.0, 2e-4])
    cases = [(graze, graze * torch.tensor([-1.0, 1.0, 1.0])), (torch.tensor([0.0, 0.6, -0.8]), torch.tensor([0.0, 0.0, 1.0])),
             (torch.tensor([0.0, 0.0, 1.0]), torch.tensor([0.6, 0.0, -0.8])), (torch.tensor([1.0, 0.0, 0.0]), torch.tensor([0.0, 1.0, 0.0])),
             (torch.tensor([0.0, 0.0, 1.0]), torch.tensor([0.0, 0.0, 1.0]))]
    wi = torch.stack([c[0] for c in cases]).float()
    wo = torch.stack([c[1] for c in cases]).float()
    wi, wo = wi / wi.norm(dim=1, keepdim=True), wo / wo.norm(dim=1, keepdim=True)
    f_r = torch.tensor([[1e4, 0.0, 1.0]]).expand(len(wi), 3)
    table = MaterialTable(model.specs, ["m"], model.latent_dim)
    with torch.no_grad():
        for name in ("alpha_x", "alpha_y"):
            table.raw[name].fill_(-17.0)  # the raw limit: roughness at its lowest
    x = space.from_table(table, seed=0)
    layout = layout_rows(wi[None], wo[None], f_r[None], torch.tensor([0]), torch.ones(1, len(wi), dtype=torch.bool),
                         torch.ones(1, len(wi), dtype=torch.bool))
    out = RowKernel(model, space)(x, layout, prior_strength=torch.ones(1), surrogate_eps=1e-3)
    assert torch.isfinite(out.objective).all() and torch.isfinite(out.val).all() and torch.isfinite(out.grad).all()


# -- the layout ----------------------------------------------------------------------------------
def test_padding_carries_no_weight_and_folds_partition_each_materials_samples():
    samples = sample_materials(synthetic_ggx(2, seed=1), 50, seed=0)
    samples = samples.subset(torch.arange(len(samples))[:80])  # material 1 keeps 30 of its 50
    wi, wo, f_r, valid = padded(samples)
    assert valid.sum(1).tolist() == [50, 30] and wi.shape == (2, 50, 3)
    folds = fold_masks(valid, 3)
    assert torch.equal(folds.sum(0), valid.long()) and (folds.sum(2) >= torch.tensor([16, 10])).all()
    # a layout row's loss is the mean over its material's valid samples only
    model = get_model("ggx")
    table = random_table(model, samples.names, 3)
    space = RowSpace(model)
    layout = layout_rows(wi, wo, f_r, torch.arange(2), valid, torch.zeros_like(valid))
    losses = RowKernel(model, space)(space.from_table(table), layout, grad=False)
    assert losses.train.tolist() == pytest.approx(per_material_loss(model, table, samples), rel=1e-5)


def test_compacting_keeps_each_rows_own_slots_in_order_at_the_front():
    """``compacted`` against a plain loop over rows: the kept slots first in their order, the rest
    copies of the row's first kept slot marked invalid, the grid as wide as the row keeping most."""
    generator = torch.Generator().manual_seed(0)
    wi, wo, f_r = (torch.randn(3, 7, 3, generator=generator) for _ in range(3))
    keep = torch.rand(3, 7, generator=generator) < 0.5
    keep[:, 2] = True
    c_wi, c_wo, c_f, valid = compacted(wi, wo, f_r, keep)
    width = int(keep.sum(1).max())
    assert valid.shape == (3, width)
    for r in range(3):
        own = [j for j in range(7) if keep[r, j]]
        slots = own + [own[0]] * (width - len(own))
        assert valid[r].tolist() == [True] * len(own) + [False] * (width - len(own))
        for got, whole in ((c_wi, wi), (c_wo, wo), (c_f, f_r)):
            assert torch.equal(got[r], whole[r, slots])
    with pytest.raises(ValueError, match="at least one slot"):
        compacted(wi, wo, f_r, torch.zeros_like(keep))


def test_windows_are_each_rows_slots_from_each_low_block_by_block():
    """``RowLayout.windows`` against a plain loop over blocks and rows; windows past the slots refused."""
    generator = torch.Generator().manual_seed(0)
    wi, wo, f_r = (torch.randn(2, 9, 3, generator=generator) for _ in range(3))
    valid = torch.rand(2, 9, generator=generator) < 0.7
    layout = layout_rows(wi, wo, f_r, torch.tensor([1, 0]), valid, ~valid)
    got = layout.windows([0, 5, 2], 4)
    assert got.rows == 6 and got.slots == 4 and got.material.tolist() == [1, 0] * 3
    for block, low in enumerate((0, 5, 2)):
        for r, m in enumerate((1, 0)):
            row, slots = block * 2 + r, slice(low, low + 4)
            # weights are the row's own (layout_rows), samples its material's
            assert torch.equal(got.train[row], valid[r, slots].float()) and torch.equal(got.val[row], (~valid)[r, slots].float())
            for flat, whole in ((got.wi, wi), (got.wo, wo), (got.f_r, f_r)):
                assert torch.equal(flat.reshape(6, 4, 3)[row], whole[m, slots])
    with pytest.raises(ValueError, match="do not fit in 9 slots"):
        layout.windows([0, 6], 4)


class _CallSpy(RowKernel):
    """A real kernel that keeps the layouts and the rows of its calls."""

    def __init__(self, *args):
        super().__init__(*args)
        self.layouts, self.xs = [], []

    def __call__(self, x, layout, **kwargs):
        self.layouts.append(layout)
        self.xs.append(x.detach().float().clone())
        return super().__call__(x, layout, **kwargs)


@pytest.mark.parametrize("lrs, subsets, lows", [((0.05, 0.2, 0.05), True, [0, 100, 200]),
                                                 ((0.05, 0.2, 0.05, 0.05), True, [0, 100, 200]),
                                                 ((0.05, 0.2, 0.05), False, [0, 0])])
def test_each_warmup_on_its_own_subset_sees_its_own_slots_inside_the_fewest_samples(lrs, subsets, lows):
    """``warmup_subsets``: warm-up ``k`` (its Adam epochs and its first L-BFGS phase) reads every
    row's slots from ``k * coarse_slots``, kept inside the samples of the row with fewest (300 here:
    a window past them would read padding); without it every warm-up reads the first slots. A
    warm-up at another's lr on the same slots (the fourth, the third without subsets) is dropped."""
    samples = sample_materials(synthetic_ggx(2, seed=23, noise_sigma=0.1), 400, seed=1)
    samples = samples.subset(torch.arange(len(samples))[:700])  # material 1 keeps 300 of its 400
    model = get_model("ggx")
    space = RowSpace(model)
    layout = Rows(samples, 0).layout(torch.arange(2))
    first = space.from_table(MaterialTable(model.specs, samples.names, model.latent_dim))
    kernel = _CallSpy(model, space)
    PlainLBFGS(iterations=5, warmup_epochs=3, coarse_slots=100, warmup_lrs=lrs, warmup_subsets=subsets
               ).fit_rows(kernel, first, layout)
    coarse = [seen for seen in kernel.layouts if seen.slots == 100]  # L-BFGS also steps fewer rows, the unsettled
    warm = [seen for seen in coarse if seen.rows == 2 * len(lows)]
    assert len(warm) >= 3 + 1 and max(seen.rows for seen in coarse) == 2 * len(lows)  # Adam's epochs, the phase
    for seen in warm:
        assert torch.equal(seen.wi, layout.windows(lows, 100).wi)


@pytest.mark.parametrize("jitter_starts", [0, 1, 2])
def test_each_jittered_start_is_one_more_start_on_every_sample(jitter_starts):
    """``jitter_starts``: the given start's first L-BFGS phase on all samples runs beside that many
    copies of it moved by ``jitter`` * N(0, 1) on every raw value (below 6 sigma, each of the 12
    columns moved), every material by the same offset (its starts do not depend on the materials
    beside it), the same copies at every call; 0 (the default) adds none."""
    samples = sample_materials(synthetic_ggx(2, seed=23, noise_sigma=0.1), 400, seed=1)
    model = get_model("ggx")
    space = RowSpace(model)
    layout = Rows(samples, 0).layout(torch.arange(2))
    first = space.from_table(MaterialTable(model.specs, samples.names, model.latent_dim))
    protocol = PlainLBFGS(iterations=5, warmup_epochs=3, coarse_slots=100, jitter_starts=jitter_starts, jitter=0.02)
    given = []
    for _ in range(2):
        kernel = _CallSpy(model, space)
        protocol.fit_rows(kernel, first, layout)
        # the rows of the first call on all 400 slots: the given starts' first phase
        given.append(next(x for x, seen in zip(kernel.xs, kernel.layouts) if seen.slots == 400))
    assert torch.equal(given[0], given[1]) and len(given[0]) == 2 * (1 + jitter_starts)
    assert torch.equal(given[0][:2], first)
    if jitter_starts:
        moved = (given[0][2:] - first.repeat(jitter_starts, 1)).abs()
        assert bool((moved > 0).all()) and float(moved.max()) < 6 * 0.02
        offsets = (given[0][2:] - first.repeat(jitter_starts, 1)).reshape(jitter_starts, 2, -1)
        assert torch.allclose(offsets[:, 0], offsets[:, 1], rtol=0, atol=4 * torch.finfo(torch.float32).eps)
    with pytest.raises(ValueError, match="invalid plain protocol"):
        PlainLBFGS(jitter_starts=-1)


# -- what each protocol promises -------------------------------------------------------------------
def _quarter_turn_canonical(params: dict) -> dict:
    """GGX parameters with ``t_theta`` in (-pi/4, pi/4]: a quarter turn of the tangent frame with
    ``alpha_x`` and ``alpha_y`` swapped is the same lobe (Heitz 2014 eq. 85 and 86: slope² and the
    projected roughness are symmetric under x -> y, y -> -x with a_x and a_y exchanged)."""
    out = dict(params)
    angle = float(out["t_theta"].reshape(-1)[0])
    turns = round(angle / (math.pi / 2))
    if turns:
        out["t_theta"] = out["t_theta"] - turns * math.pi / 2
        if turns % 2:
            out["alpha_x"], out["alpha_y"] = params["alpha_y"], params["alpha_x"]
    return out


@pytest.mark.parametrize("kernel", ["torch", pytest.param("jit", marks=pytest.mark.skipif(
    not jit_available(), reason="Dr.Jit's LLVM backend is not available (neuenh[export]; libLLVM 17+)"))])
def test_plain_lbfgs_recovers_a_ggx_material(clean_ggx, kernel):
    material, samples = clean_ggx
    model = get_model("ggx")
    result = fit_materials(model, samples, PlainLBFGS(kernel=kernel))
    truth = {k: torch.tensor(v, dtype=torch.float32) for k, v in material.metadata["params"].items()}
    # The floor: the float32 model's own loss at the true parameters (its rounding against the data).
    floor = float(log_l1(model.evaluate(samples.wi, samples.wo, truth), samples.f_r, samples.wi).double().mean())
    # The surrogate's last phase resolves residuals down to its eps (1e-3): the fit ends within that.
    assert result.loss <= floor + SURROGATE_EPS[-1]
    fitted = {k: v[0] for k, v in result.materials.values().items()}
    # Anisotropic GGX is the same lobe with the tangent turned by a quarter turn and the roughnesses
    # swapped: compare both in the form whose tangent angle lies within an eighth turn of zero.
    truth, fitted = _quarter_turn_canonical(truth), _quarter_turn_canonical(fitted)
    # A mean log residual of 1e-3 moves a parameter by about that much relative (the f_r of every
    # parameter here is smooth in it, of order-one sensitivity at 5,000 well-spread pairs).
    for name, value in truth.items():
        assert fitted[name].tolist() == pytest.approx(value.tolist(), rel=SURROGATE_EPS[-1], abs=SURROGATE_EPS[-1]), name


def test_plain_lbfgs_warms_up_on_a_subset_and_is_never_worse_than_its_start_alone():
    """More samples than ``coarse_slots``: the warm-up start runs its first phase on a subset, the
    paper's start on every sample; the fit keeps the better, so it is no worse than L-BFGS from the
    paper's start alone on all samples, and both are far below the paper start's own loss."""
    (material,) = synthetic_ggx(1, seed=21, noise_sigma=0.1)
    samples = sample_materials([material], 5000, seed=0)
    model = get_model("ggx")
    protocol = PlainLBFGS(iterations=60, coarse_slots=64)
    result = fit_materials(model, samples, protocol)
    rows, space = Rows(samples, 0), RowSpace(model)
    layout = rows.layout(torch.arange(1))
    first = space.from_table(MaterialTable(model.specs, samples.names, model.latent_dim))
    kernel = RowKernel(model, space)
    with torch.no_grad():
        start_loss = evaluate_rows(kernel, first, layout).train
    alone, _ = lbfgs_rows(kernel, first, layout, 60)
    alone_loss = evaluate_rows(kernel, alone.float(), layout).train
    # The fine phase runs the paper start beside the warm-up start: a batch of two rows rounds
    # differently from one (~1e-10), so both stop near the same minimum within L-BFGS's own tolerance
    # (a relative decrease below 1e-4 for 3 iterations), not bit for bit.
    assert result.loss <= float(alone_loss[0]) * (1 + 3e-4) and float(alone_loss[0]) < 0.5 * float(start_loss[0])
    assert result.protocol["coarse_slots"] == 64


def test_each_warmup_lr_of_a_plain_fit_is_one_more_start():
    """``warmup_lrs``: one warm-up start per lr (one Adam batch), all beside the given start, each
    material keeping the lowest end point; an empty or non-positive lr is refused. The given start has
    every raw parameter at -8, where the sigmoid's slope is 3e-4: L-BFGS from it stays near it, and so
    does a warm-up at lr 0.01 (30 Adam epochs move a parameter at most ~0.3), while one at lr 1.0 can
    move it out of saturation. So the fit with both lrs must end no higher than either alone (to 5 %:
    the starts as rows of other batches round differently), and well below the lr 0.01 fit on the
    first material (1.46x there when written). The test's earlier form relied on a basin chosen by
    rounding alone, which held on one CPU and not on another."""
    samples = sample_materials(synthetic_ggx(3, seed=22, noise_sigma=0.1), 400, seed=1)
    model = get_model("ggx")
    saturated = MaterialTable(model.specs, samples.names, model.latent_dim,
                              {s.name: torch.full((len(samples.names), s.width), -8.0) for s in model.specs})
    fit = lambda lrs: fit_materials(model, samples, PlainLBFGS(iterations=100, warmup_epochs=30, coarse_slots=100,
                                                               warmup_lrs=lrs), start=saturated)
    both, small_lr, large_lr = fit((0.01, 1.0)), fit((0.01,)), fit((1.0,))
    for material, loss in enumerate(both.losses):
        assert loss <= 1.05 * min(small_lr.losses[material], large_lr.losses[material])
    assert both.losses[0] < 0.8 * small_lr.losses[0]
    assert both.protocol["warmup_lrs"] == (0.01, 1.0)
    for invalid in ((), (0.05, 0.0)):
        with pytest.raises(ValueError, match="invalid plain protocol"):
            PlainLBFGS(warmup_lrs=invalid)


def test_plain_lbfgs_beats_the_paper_protocol_at_the_same_budget(clean_ggx):
    _, samples = clean_ggx
    model = get_model("ggx")
    fast = fit_materials(model, samples, PlainLBFGS(iterations=60))
    paper = fit_materials(model, samples, PaperRMSProp(epochs=60))
    assert fast.loss < 0.5 * paper.loss


def _corrected(out: int, inp: int, rank: int | None) -> int:
    """Free parameters of one layer's correction: a dense delta and bias, or ``U V`` factors and a bias."""
    return out * inp + out if rank is None else out * rank + rank * inp + out


@pytest.mark.parametrize("capacity, ranks", [("last-layer", None), ("low-rank", 2), ("rank-8", 8), ("full", "dense")])
def test_parameters_per_material_at_a_capacity_follow_from_the_layer_shapes(enhanced, capacity, ranks):
    """What the report and every count show: the analytical and latent parameters, then each corrected
    layer's, counted here from the modules' weight shapes alone."""
    count = enhanced.n_material_params()
    for module in enhanced.neural.values():
        shapes = [tuple(layer.weight.shape) for layer in module.layers]
        count += _corrected(*shapes[-1], None)  # the last layer is dense at every capacity with corrections
        if ranks is not None:
            count += sum(_corrected(*shape, None if ranks == "dense" else ranks) for shape in shapes[:-1])
    assert Adaptive().n_params(enhanced, (capacity, 1e-3))[0] == count


def test_options_name_one_protocol_with_its_own_budget():
    plain, enhanced = get_model("ggx"), get_model("ggx", state=PAPER_STATE, seed=0)
    assert FitOptions(lbfgs_iterations=40).protocol_for(plain) == PlainLBFGS(iterations=40)
    assert FitOptions(method="paper", epochs=50).protocol_for(enhanced) == PaperRMSProp(epochs=50)
    assert FitOptions(capacity="latent", epochs=70).protocol_for(enhanced) == LatentAdam(epochs=70)
    adaptive = FitOptions(capacity="auto").protocol_for(enhanced)
    assert isinstance(adaptive, Adaptive) and {"original", "analytical"} <= set(adaptive.capacities)
    assert FitOptions(capacity="last-layer").protocol_for(enhanced).capacities == ("last-layer",)
    assert PaperRMSProp() == PaperRMSProp(epochs=1000, lr=1e-3)
    assert (PlainLBFGS(iterations=7).budget_epochs, LatentAdam(epochs=9).budget_epochs,
            Adaptive(latent_epochs=10).budget_epochs) == (7, 9, 10)
    for bad, match in (({"method": "newton"}, "fit method"), ({"capacity": "huge"}, "capacity"),
                       ({"epochs": 0}, "epochs"), ({"starts": "random"}, "starts")):
        with pytest.raises(ValueError, match=match):
            FitOptions(**bad)


# Each protocol's work for two materials of 300 and 100 samples (400 in all): the measurements it
# reads times the epochs it reads them, counted by hand from the protocol's documented structure.
@pytest.mark.parametrize("protocol, work", [
    (PlainLBFGS(iterations=7), 400 * 7),
    (PaperRMSProp(epochs=5), 400 * 5),
    (LatentAdam(epochs=9, sample_cap=None), 400 * 9),
    (LatentAdam(epochs=9, sample_cap=150), (150 + 100) * 9),  # at most 150 of each material's
    (LatentAdam(epochs=10, coarse_slots=200), (200 + 100) * 5 + 400 * 5),  # 200 of each until the narrowing at half
    (LatentAdam(epochs=10, sample_cap=150, coarse_slots=200), (150 + 100) * 10),
    (Adaptive(latent_epochs=10), (400 + 400) * 10),  # one validation fold, then the fit of all
    (Adaptive(latent_epochs=10, validation_folds=3), (3 * 400 + 400) * 10),
    (Adaptive(latent_epochs=10, validation_cap=150), ((150 + 100) + 400) * 10),  # chooses on at most 150
    (Adaptive(latent_epochs=10, capacities=("latent",)), 400 * 10),  # a single candidate: no validation
])
def test_a_protocols_work_is_the_measurements_it_reads_times_its_epochs(protocol, work):
    """``FitProtocol.work``, what a service's limit on one fit bounds (``NEUENH_MAX_FIT_WORK``)."""
    samples = Samples.concat([sample_materials(synthetic_ggx(1, seed=s), n, seed=s) for s, n in ((1, 300), (2, 100))])
    assert samples.counts().tolist() == [300, 100] and protocol.work(samples) == work


def test_latent_fit_keeps_each_materials_best_start(two_zoo_materials, enhanced):
    """The analytical starts include the paper's: with the same budget never worse than the
    paper's start alone by more than the rounding of a stacked run."""
    samples = two_zoo_materials
    trained = MaterialTable(enhanced.specs, ("t1", "t2"), enhanced.latent_dim,
                            latent=torch.tensor([[0.1] * 27, [0.3] * 27]))
    paper = LatentAdam(epochs=40, starts="paper").fit(enhanced, samples)
    best = LatentAdam(epochs=40).fit(enhanced, samples, trained=trained)
    for mine, theirs in zip(best.losses, paper.losses):
        assert mine <= theirs * 1.02


def test_a_latent_fit_over_its_cap_fits_a_seeded_draw_of_each_materials_samples(enhanced, two_zoo_materials):
    """``sample_cap``: a material with more samples is fitted to ``Samples.at_most``'s draw of them —
    the very fit of that draw with no cap —; under the cap the fit is the uncapped one."""
    samples = two_zoo_materials  # 600 samples of each material
    capped = LatentAdam(epochs=9, sample_cap=200).fit(enhanced, samples, seed=2)
    drawn = LatentAdam(epochs=9, sample_cap=None).fit(enhanced, samples.at_most(200, seed=2), seed=2)
    assert capped.losses == drawn.losses and torch.equal(capped.materials.latent, drawn.materials.latent)
    uncapped = LatentAdam(epochs=9, sample_cap=None).fit(enhanced, samples, seed=2)
    assert LatentAdam(epochs=9, sample_cap=600).fit(enhanced, samples, seed=2).losses == uncapped.losses
    assert capped.losses != uncapped.losses
    assert capped.protocol["sample_cap"] == 200 and LatentAdam().sample_cap == 20_000
    with pytest.raises(ValueError, match="invalid latent protocol"):
        LatentAdam(sample_cap=0)



def test_a_latent_fit_narrows_to_each_materials_best_start_after_the_share_of_epochs_it_is_given(
        enhanced, two_zoo_materials, monkeypatch):
    """``narrow_at``: after that share of the epochs each material keeps its start of lowest loss. At 0
    that is before any step, so the fit is the fit from that start alone, to the bit; at 0.5 of 8 epochs
    the last stage steps all starts' rows 4 times, then one row a material 4 times."""
    trained, samples = _codes(enhanced, 6, seed=5), two_zoo_materials
    first = LatentAdam(epochs=8, screened=2, narrow_at=0.0)
    space, rows = RowSpace(enhanced), Rows(samples, 1)
    starts = torch.stack(first.starts_of(enhanced, rows, trained, seed=1))  # (k, m, dim)
    k, m, _ = starts.shape
    loss = evaluate_rows(RowKernel(enhanced, space), starts.reshape(k * m, -1),
                         rows.layout(torch.arange(m).repeat(k))).train.reshape(k, m)
    best = space.to_table(starts[loss.argmin(0), torch.arange(m)],
                          MaterialTable(enhanced.specs, samples.names, enhanced.latent_dim))
    assert first.fit(enhanced, samples, trained=trained, seed=1).losses == \
        first.fit(enhanced, samples, start=best, seed=1).losses

    steps = []  # the rows of every step of the last stage (its kernel is the last one built)

    class Counting(RowKernel):
        def __call__(self, x, layout, *, grad=True, **kw):
            if grad:
                steps.append(len(x))
            return super().__call__(x, layout, grad=grad, **kw)

    def counting_kernel(model, space, kernel="torch", work=None):
        steps.clear()
        return Counting(model, space)

    monkeypatch.setattr("neuenh.fit.protocols.row_kernel", counting_kernel)
    half = LatentAdam(epochs=8, screened=2, narrow_at=0.5)
    assert half.fit(enhanced, samples, trained=trained, seed=1).protocol["narrow_at"] == 0.5
    assert steps == [k * m] * 4 + [m] * 4
    for invalid in (1.0, -0.1):
        with pytest.raises(ValueError, match="invalid latent protocol"):
            LatentAdam(narrow_at=invalid)

def test_a_coarse_latent_fit_races_its_starts_on_its_first_slots_and_runs_the_kept_one_on_all(
        enhanced, two_zoo_materials, monkeypatch):
    """``coarse_slots``: the stacked starts step on each row's first ``coarse_slots`` slots (a random
    subset) until the narrowing, the start each material keeps on all its slots, chosen by its loss on
    all of them; the starts are made on all of them; with at least as many slots as samples it is the
    fit without, to the bit."""
    trained, samples = _codes(enhanced, 6, seed=5), two_zoo_materials  # 600 samples of each material
    plain = LatentAdam(epochs=8, screened=2).fit(enhanced, samples, trained=trained, seed=1)
    assert LatentAdam(epochs=8, screened=2, coarse_slots=600).fit(enhanced, samples, trained=trained,
                                                                  seed=1).losses == plain.losses
    steps = []  # (rows, slots) of every step

    class Counting(RowKernel):
        def __call__(self, x, layout, *, grad=True, **kw):
            if grad:
                steps.append((len(x), layout.slots))
            return super().__call__(x, layout, grad=grad, **kw)

    monkeypatch.setattr("neuenh.fit.protocols.row_kernel", lambda model, space, kernel="torch", work=None:
                        Counting(model, space))
    coarse = LatentAdam(epochs=8, screened=2, screen_samples=100, coarse_slots=250)
    result = coarse.fit(enhanced, samples, trained=trained, seed=1)
    m, k = len(samples.names), 4  # starts: the paper's, two imitations, the screened codes' winner
    assert steps[-8:] == [(k * m, 250)] * 4 + [(m, 600)] * 4  # the last stage: all starts, then the kept ones
    assert {slots for _, slots in steps[:-8]} == {600, coarse.screen_samples}, steps  # the starts, their screen
    assert result.losses_on(enhanced, samples) == pytest.approx(result.losses, rel=1e-4)
    with pytest.raises(ValueError, match="invalid latent protocol"):
        LatentAdam(coarse_slots=0)


def test_adam_rows_scale_each_rows_learning_rate():
    """``lr_scale``: one batch of two copies of a start, the second at a quarter of the lr. Adam's
    first step is lr * m / (sqrt(v) + eps) with m and v the same for both copies, so the second
    copy moves a quarter as far, up to float32's rounding of x - step (x of order one: ~6e-8)."""
    samples = sample_materials(synthetic_ggx(1, seed=4, noise_sigma=0.1), 300, seed=2)
    model = get_model("ggx")
    space = RowSpace(model)
    start = space.from_table(MaterialTable(model.specs, samples.names, model.latent_dim))
    layout = Rows(samples, 0).layout(torch.tensor([0, 0]))
    moved = adam_rows(RowKernel(model, space), start.repeat(2, 1), layout, Adam(1, 0.1),
                      lr_scale=torch.tensor([1.0, 0.25])).x - start
    assert moved[0].abs().max() > 0.05
    assert moved[1].tolist() == pytest.approx((0.25 * moved[0]).tolist(), abs=1e-6)


def test_stacked_adam_narrowed_onto_more_slots_chooses_there_and_needs_starts():
    """``narrowed_layout``: each group's best is its best on that layout, not on the one stepped before
    (here its first slots, fitted to other targets: there the other start is the better one)."""
    materials = synthetic_ggx(1, seed=4, noise_sigma=0.0)
    samples = sample_materials(materials, 400, seed=2)
    model = get_model("ggx")
    space = RowSpace(model)
    truth = {s.name: torch.as_tensor([materials[0].metadata["params"][s.name]], dtype=torch.float64) for s in model.specs}
    true = space.from_table(MaterialTable(model.specs, samples.names, model.latent_dim,
                                          {s.name: s.to_raw(truth[s.name]).float() for s in model.specs}))
    other = space.from_table(MaterialTable(model.specs, samples.names, model.latent_dim))
    wi, wo, f_r, valid = padded(samples)
    material = torch.tensor([0, 0])
    full = layout_rows(wi, wo, f_r, material, valid[material], torch.zeros(2, valid.shape[1], dtype=torch.bool))
    kernel = RowKernel(model, space)
    values, _ = space.values(other)
    as_other = model.forward_indexed(full.wi[:400], full.wo[:400], values, None, full.select([0]).grid).detach()
    stepped = full.with_targets(as_other.repeat(2, 1)).chunk(0, 50)  # where the other start fits best
    starts = torch.cat([true, other])
    assert evaluate_rows(kernel, starts, stepped).train.argmin() == 1
    assert evaluate_rows(kernel, starts, full).train.argmin() == 0
    result = adam_rows(kernel, starts, stepped, Adam(1, 1e-9), groups=material, narrow_at=0.0, narrowed_layout=full)
    assert result.rows.tolist() == [0] and float(result.train[0]) < 1e-4
    with pytest.raises(ValueError, match="narrowed layout"):
        adam_rows(kernel, starts, stepped, Adam(1, 1e-3), narrowed_layout=full)


def _codes(model, n, seed):
    """A training table of ``n`` materials with spread-out latent codes (``_random_table``'s)."""
    return random_table(model, tuple(f"t{i}" for i in range(n)), seed)


@pytest.mark.parametrize("slots_at_once", [SCREEN_SLOTS, 2_500])  # the 12 codes in one group; in groups of four
def test_screened_codes_are_the_training_codes_that_fit_best_as_they_are(enhanced, two_zoo_materials, slots_at_once):
    """Each material's screened codes sit beside its analytical row, lowest log-L1 first — ranked
    here by the model's own forward pass (``per_material_loss``), not by the fit's kernel — whether
    the codes are scored all at once or in groups."""
    samples, trained = two_zoo_materials, _codes(enhanced, 12, seed=1)
    rows, space = Rows(samples, seed=0), RowSpace(enhanced)
    n_base = space.base_dim - enhanced.latent_dim
    base = torch.rand(rows.materials, n_base, generator=torch.Generator().manual_seed(2)) - 0.5
    screened = LatentAdam(screened=3).screened_codes(enhanced, rows, trained, base, slots_at_once)
    assert screened.shape == (rows.materials, 3, space.dim)
    for i in range(rows.materials):
        mine = samples.of_material(i)
        mine = Samples(mine.wi, mine.wo, mine.f_r, torch.zeros(len(mine), dtype=torch.long), samples.names[i : i + 1])
        losses = []
        for code in trained.latent:
            table = space.to_table(torch.cat([base[i], code])[None],
                                   MaterialTable(enhanced.specs, mine.names, enhanced.latent_dim))
            losses.append(per_material_loss(enhanced, table, mine)[0])
        assert all(torch.equal(row[:n_base], base[i]) for row in screened[i])
        chosen = [int(torch.nonzero((trained.latent == row[n_base:]).all(1))[0]) for row in screened[i]]
        # the kernel and the forward pass round differently: a per-sample log-L1 is off by a few float32
        # eps per layer of the modules (absolute: log(1 + x) has slope <= 1), so ranks may swap only there
        rounding = 64 * FLOAT32_EPS
        assert [losses[c] for c in chosen] == pytest.approx(sorted(losses)[:3], abs=rounding)


def test_a_material_measured_at_a_training_code_starts_there(enhanced):
    """A material the model itself renders at one of the training codes (and known analytical
    parameters): that code is screened first, and the start raced from it fits better than any
    other training code as it is."""
    truth = random_table(enhanced, ("m",), seed=4)
    trained = _codes(enhanced, 10, seed=5)
    with torch.no_grad():
        truth.latent.copy_(trained.latent[7])
    wi, wo = (d.float() for d in sample_directions(800, seed=6, near_mirror=0.3))
    with torch.no_grad():
        f_r = enhanced.forward_indexed(wi, wo, truth.values(), truth.latent, torch.zeros(len(wi), dtype=torch.long))
    samples = Samples(wi, wo, f_r.clamp_min(0), torch.zeros(len(wi), dtype=torch.long), ("m",))
    rows, space = Rows(samples, seed=0), RowSpace(enhanced)
    x_true = space.from_table(truth)
    base, protocol = x_true[:, : space.base_dim - enhanced.latent_dim], LatentAdam(screened=3)
    screened = protocol.screened_codes(enhanced, rows, trained, base)
    assert torch.equal(screened[0, 0], x_true[0])
    [start] = protocol.screened_starts(enhanced, rows, trained, base)
    loss = lambda x: float(evaluate_rows(RowKernel(enhanced, space), x, rows.layout(torch.zeros(1, dtype=torch.long))).train[0])
    assert loss(start) < loss(screened[0, 1:2])


def test_the_encoders_prediction_is_one_more_start_of_the_latent_fit(enhanced):
    """With an encoder (``neuenh.encoder``'s contract: a material's samples -> its parameters; here
    the one that knows the answer, a material the model itself renders), its prediction joins the
    latent fit's own starts, wins the race and ends an order of magnitude below the fit from the
    protocol's own starts alone (×13 at 12 epochs on AMD EPYC); a given ``start`` or the paper's
    starts take no encoder start, and the report says which fit had one."""
    truth = random_table(enhanced, ("m",), seed=4)
    wi, wo = (d.float() for d in sample_directions(800, seed=6, near_mirror=0.3))
    with torch.no_grad():
        f_r = enhanced.forward_indexed(wi, wo, truth.values(), truth.latent, torch.zeros(len(wi), dtype=torch.long))
    samples = Samples(wi, wo, f_r.clamp_min(0), torch.zeros(len(wi), dtype=torch.long), ("m",))

    class KnowsTheAnswer:
        def encode(self, fitted: Samples) -> MaterialTable:
            assert fitted.names == samples.names and len(fitted) == len(samples)
            return truth

    trained, protocol = _codes(enhanced, 6, seed=5), LatentAdam(epochs=12)
    own = protocol.fit(enhanced, samples, trained=trained)
    with_encoder = protocol.fit(enhanced, samples, trained=trained, encoder=KnowsTheAnswer())
    assert not own.protocol["encoder_start"] and with_encoder.protocol["encoder_start"]
    assert with_encoder.losses[0] < own.losses[0] / 4
    start = random_table(enhanced, ("m",), seed=9)
    for fit in (protocol.fit(enhanced, samples, start=start, encoder=KnowsTheAnswer()),
                LatentAdam(epochs=12, starts="paper").fit(enhanced, samples, encoder=KnowsTheAnswer())):
        assert not fit.protocol["encoder_start"]


def test_screening_reads_only_the_fits_own_slots_and_needs_training_codes(enhanced, two_zoo_materials):
    samples, trained = two_zoo_materials, _codes(enhanced, 6, seed=3)
    rows = Rows(samples, seed=0)
    base = torch.zeros(rows.materials, RowSpace(enhanced).base_dim - enhanced.latent_dim)
    train = fold_masks(rows.valid, 2)[0]
    protocol = LatentAdam(epochs=12, screened=2)
    [clean] = protocol.screened_starts(enhanced, rows, trained, base, train)
    rows.f_r = torch.where(train[..., None], rows.f_r, 1e6)  # what the fit does not see is changed
    [changed] = protocol.screened_starts(enhanced, rows, trained, base, train)
    assert clean.shape == (rows.materials, RowSpace(enhanced).dim) and torch.equal(clean, changed)
    assert protocol.screened_starts(enhanced, rows, None, base) == []
    assert LatentAdam(screened=0).screened_starts(enhanced, rows, trained, base) == []
    with pytest.raises(ValueError, match="invalid latent protocol"):
        LatentAdam(screened=-1)


def test_stacked_adam_narrows_to_each_groups_best_start():
    """Two materials, two starts each: the true parameters of one material are a start of that
    material only. After a quarter of the epochs each material keeps its better start, so both
    end near zero loss, and the result has one row per material."""
    materials = synthetic_ggx(2, seed=4, noise_sigma=0.0)
    samples = sample_materials(materials, 2000, seed=2)
    model = get_model("ggx")
    truth = {s.name: torch.stack([s.to_raw(torch.as_tensor(m.metadata["params"][s.name], dtype=torch.float64))
                                  for m in materials]).float() for s in model.specs}
    space = RowSpace(model)
    default = space.from_table(MaterialTable(model.specs, samples.names, model.latent_dim))
    true = space.from_table(MaterialTable(model.specs, samples.names, model.latent_dim, truth))
    start_a = torch.stack([true[0], default[1]])  # material 0 true, 1 default
    start_b = torch.stack([default[0], true[1]])
    wi, wo, f_r, valid = padded(samples)
    material = torch.tensor([0, 1, 0, 1])
    layout = layout_rows(wi, wo, f_r, material, valid[material], torch.zeros(4, valid.shape[1], dtype=torch.bool))
    result = adam_rows(RowKernel(model, space), torch.cat([start_a, start_b]), layout, Adam(8, 1e-4), groups=material)
    assert result.rows.tolist() == [0, 3] and max(result.train) < 1e-3


ADAPTIVE = dict(latent_epochs=20, correction_epochs=15, lbfgs_iterations=40, priors=(1e-2,), folds=3)


def test_adaptive_picks_the_analytical_capacity_on_a_table_ggx_generated(enhanced):
    """A clean GGX material: the analytical model represents it exactly, so its cross-validation
    loss is the lowest and the adaptive fit is the analytical-only fit — its rows on all samples run
    as ``PlainLBFGS`` runs them, plus a third start at the validation fit, so never worse."""
    samples = sample_materials(synthetic_ggx(1, seed=9, noise_sigma=0.0), 300, seed=0)
    result = Adaptive(**ADAPTIVE).fit(enhanced, samples)
    scores = result.details[0]["cv"]
    assert result.capacity(0) == "analytical" == min(scores, key=scores.get)
    record = result.materials.as_params(0)
    assert record.capacity == "analytical" and not record.corrections
    own, params = result.material_model(enhanced, 0)
    assert not own.has_modules and params.latent is None and params.n_params == own.used_specs().total_width
    plain = PlainLBFGS(iterations=ADAPTIVE["lbfgs_iterations"]).fit(own, samples)
    assert result.losses[0] <= plain.losses[0] < 1e-3


def test_the_choice_is_the_simplest_candidate_within_the_standard_errors_of_the_lowest():
    """The one-standard-error rule on hand-made scores, three candidates of 12, 42 and 240
    parameters and four materials: the lowest when nothing simpler is within reach, the simplest
    within reach otherwise, equal scores the simplest."""
    loss = torch.tensor([[0.050, 0.050, 0.020, 0.030],
                         [0.040, 0.031, 0.020, 0.030],
                         [0.030, 0.030, 0.010, 0.030]], dtype=torch.float64)
    error = torch.full_like(loss, 0.002)
    sizes = [(12, 0.0), (42, 0.0), (240, 0.0)]
    assert simplest_within(loss, error, sizes, 1.0) == [2, 1, 2, 0]
    assert simplest_within(loss, error, sizes, 0.0) == [2, 2, 2, 0]
    assert simplest_within(loss, error, sizes, 100.0) == [0, 0, 0, 0]
    # of equal sizes the stronger prior (the larger strength, a lower key) first
    assert simplest_within(loss, error, [(42, 0.0), (42, -0.01), (240, 0.0)], 1.0) == [2, 1, 2, 1]


def test_a_gaps_standard_error_is_the_spread_of_the_paired_differences():
    """Against numpy on hand-made losses: per material, the candidate of lowest mean is the
    reference, and each candidate's gap error is the sample standard deviation of its per-sample
    differences to it over the root of their count; padding slots (NaN here) count for nothing."""
    generator = torch.Generator().manual_seed(3)
    per_sample = torch.rand(3, 2, 6, generator=generator, dtype=torch.float64)
    held_out = torch.ones(2, 6, dtype=torch.bool)
    held_out[1, 4:] = False
    per_sample[:, 1, 4:] = torch.nan
    errors = gap_errors(per_sample, held_out)
    for i, n in ((0, 6), (1, 4)):
        losses = per_sample[:, i, :n].numpy()
        gaps = losses - losses[losses.mean(1).argmin()]
        expected = gaps.std(1, ddof=1) / np.sqrt(n)
        np.testing.assert_allclose(errors[:, i].numpy(), expected, rtol=1e-12, atol=1e-15)


def test_the_original_capacity_is_the_plain_fit_of_the_model_the_search_started_from():
    """The shipped model keeps alternative terms (Oren–Nayar, hazy GGX): its ``analytical`` capacity
    is that formula, its ``original`` one plain GGX: evaluated as plain GGX is, fitted as it is (to
    where L-BFGS's last surrogate phase resolves the loss, ``SURROGATE_EPS[-1]``: the graph's unused
    parameters change the rows' layout, so the float32 sums), and a material there is one a bundle of
    the model cannot hold."""
    shipped, _ = load_model("enhanced-ggx")
    samples = sample_materials(synthetic_ggx(1, seed=4), 200, seed=0)
    original = Adaptive(capacities=("original",), lbfgs_iterations=30).fit(shipped, samples)
    plain_model = get_model("ggx")
    plain = PlainLBFGS(iterations=30).fit(plain_model, samples)
    own, params = original.material_model(shipped, 0)
    assert own.describe() == plain_model.describe() != capacity_space(shipped, "analytical")[0].describe()
    assert params.capacity == "original" and params.n_params == plain.material_model(plain_model, 0)[1].n_params == 12
    assert original.losses == pytest.approx(plain.losses, abs=SURROGATE_EPS[-1]) and original.at_own_capacity
    # the fitted values evaluated by plain GGX itself: the same per-sample float32 arithmetic, summed
    # in another order (a few float32 eps of the mean)
    from_plain = MaterialTable(plain_model.specs, samples.names, plain_model.latent_dim,
                               {name: original.materials.raw[name].detach() for name in plain_model.specs.names})
    assert original.losses == pytest.approx(per_material_loss(plain_model, from_plain, samples), rel=1e-6)


@pytest.mark.parametrize("capacity", ["analytical", "last-layer"])
def test_a_table_on_its_own_is_measured_at_each_materials_own_capacity(enhanced, capacity):
    """A fit's table alone, as a bundle holds it, measures what the fit measures: ``heldout_log_l1``
    and ``predict_f_r`` on the table equal them on the ``FitResult`` and an independent path — the
    capacity's model built by hand (the graph's analytical state; or a copy of the model with the
    record's corrections added to its weights) reading the same values without the record's capacity.
    ``per_material_loss``, which reads every row with the fitting model alone, refuses that table."""
    samples = sample_materials(synthetic_zoo(1, seed=6), 300, seed=0)
    test = sample_materials(synthetic_zoo(1, seed=6), 2000, seed=7)
    result = Adaptive(**{**ADAPTIVE, "capacities": (capacity,)}).fit(enhanced, samples)
    table = result.materials
    record = table.as_params(0)
    if capacity == "analytical":
        by_hand = enhanced.enhance(enhanced.analytical_state(keep_alternatives=True), 0)
    else:
        assert record.corrections
        by_hand = copy.deepcopy(enhanced)
        weights = by_hand.neural.state_dict()
        by_hand.neural.load_state_dict({k: w + record.corrections.get(k, 0) for k, w in weights.items()})
    bare = MaterialTable(by_hand.specs, table.names, by_hand.latent_dim,
                         {name: table.raw[name] for name in by_hand.specs.names},
                         table.latent if by_hand.latent_dim else None)
    expected = per_material_loss(by_hand, bare, test)
    assert heldout_log_l1(enhanced, table, test) == heldout_log_l1(enhanced, result, test)
    assert heldout_log_l1(enhanced, table, test) == pytest.approx(expected, rel=1e-5)
    assert torch.equal(predict_f_r(enhanced, table, test), predict_f_r(enhanced, result, test))
    with pytest.raises(ValueError, match=re.escape(f"fitted at their own capacity: {table.names[0]} ({capacity}")):
        per_material_loss(enhanced, table, test)


def test_adaptive_never_ends_worse_held_out_than_the_analytical_fit(enhanced):
    """Materials GGX cannot represent (the synthetic zoo): per material the adaptive fit's held-out
    loss is at most the analytical-only fit's — equal when it keeps the analytical capacity (the
    same fit, batched beside other rows: equal up to where L-BFGS ends on differently rounded float32
    sums, which its last surrogate phase resolves to ``SURROGATE_EPS[-1]``), and where it frees more,
    lower (up to the held-out sample's own noise, 2 % of the loss)."""
    materials = synthetic_zoo(2, seed=5)
    samples, test = sample_materials(materials, 300, seed=0), sample_materials(materials, 3000, seed=5)
    adaptive = Adaptive(**ADAPTIVE).fit(enhanced, samples)
    analytical = Adaptive(capacities=("analytical",), lbfgs_iterations=ADAPTIVE["lbfgs_iterations"]).fit(enhanced, samples)
    for mine, theirs, i in zip(adaptive.losses_on(enhanced, test), analytical.losses_on(enhanced, test), range(2)):
        if adaptive.capacity(i) == "analytical":
            assert mine <= theirs + SURROGATE_EPS[-1]
        else:
            assert mine <= theirs * 1.02


def test_an_adaptive_fit_over_its_cap_chooses_on_a_seeded_draw_and_fits_all_the_samples(enhanced, two_zoo_materials):
    """``validation_cap``: the validation losses are those of ``Samples.at_most``'s draw (the uncapped
    fit of that draw scores the same candidates the same), the chosen candidate is then fitted to every
    sample (its loss is measured on all of them); under the cap the fit is the uncapped one."""
    samples = two_zoo_materials  # 600 samples of each material
    budget = dict(latent_epochs=6, correction_epochs=4, lbfgs_iterations=5, priors=(1e-2,), folds=2,
                  capacities=("analytical", "latent", "last-layer"))
    capped = Adaptive(**budget, validation_cap=150).fit(enhanced, samples, seed=1)
    drawn = Adaptive(**budget, validation_cap=None).fit(enhanced, samples.at_most(150, seed=1), seed=1)
    assert [d["cv"] for d in capped.details] == [d["cv"] for d in drawn.details]
    assert [capped.capacity(i) for i in range(2)] == [drawn.capacity(i) for i in range(2)]
    assert capped.losses_on(enhanced, samples) == pytest.approx(capped.losses, rel=1e-4)  # all 600 samples
    assert capped.losses != drawn.losses_on(enhanced, samples)  # fitted to more than the draw
    uncapped = Adaptive(**budget, validation_cap=None).fit(enhanced, samples, seed=1)
    assert Adaptive(**budget, validation_cap=600).fit(enhanced, samples, seed=1).losses == uncapped.losses
    assert capped.losses != uncapped.losses and Adaptive().validation_cap == 20_000
    with pytest.raises(ValueError, match="invalid adaptive protocol"):
        Adaptive(validation_cap=2)


def test_a_candidates_validation_loss_is_its_fit_of_the_other_samples_scored_on_the_held_out_fold(enhanced):
    """The analytical candidate's validation loss against an independent path: the held-out fold's
    samples taken out of the table by hand, ``PlainLBFGS`` fitted to the rest as a material of its
    own, its loss measured on the fold. Equal up to where L-BFGS ends on a differently ordered sum:
    its last surrogate phase resolves the loss to ``SURROGATE_EPS[-1]`` (noisy GGX materials, so the
    analytical model's minimum is unique); scoring the fit's own samples instead would be off by
    the noise's generalisation gap, several times that."""
    samples = sample_materials(synthetic_ggx(2, seed=4), 150, seed=0)
    protocol = Adaptive(capacities=("analytical",), lbfgs_iterations=100, folds=3)
    rows = Rows(samples, seed=0)
    scores, _ = protocol.cross_validate(enhanced, rows, None, None, seed=0)
    analytical, _ = capacity_space(enhanced, "analytical")
    held_out = fold_masks(rows.valid, 3)[0]
    for i, name in enumerate(samples.names):
        part = lambda mask: Samples(rows.wi[i][mask], rows.wo[i][mask], rows.f_r[i][mask],
                                    torch.zeros(int(mask.sum()), dtype=torch.long), (name,))
        fitted = PlainLBFGS(iterations=100).fit(analytical, part(rows.valid[i] & ~held_out[i]))
        expected = per_material_loss(analytical, fitted.materials, part(held_out[i]))[0]
        assert float(scores.loss[("analytical", None)][i]) == pytest.approx(expected, abs=SURROGATE_EPS[-1])


def test_corrections_are_the_materials_own_keyed_like_the_module_weights(enhanced, two_zoo_materials):
    """A capacity with corrections: each material's record holds dense deltas keyed like
    ``model.neural.state_dict()`` and shaped like those weights, its parameter count includes the
    corrections' free parameters, and the model evaluates the record with them (the fit loss)."""
    samples = two_zoo_materials
    result = Adaptive(capacities=("last-layer",), latent_epochs=20, correction_epochs=20).fit(enhanced, samples)
    shapes = {k: v.shape for k, v in enhanced.neural.state_dict().items()}
    record = result.materials.as_params(0)
    assert record.capacity == "last-layer"
    assert set(record.corrections) == {f"{p}.layers.3.{w}" for p in enhanced.neural for w in ("weight", "bias")}
    assert all(v.shape == shapes[k] for k, v in record.corrections.items())
    assert enhanced.used_params(record).n_params == enhanced.n_material_params() + sum(
        shapes[k].numel() for k in record.corrections)
    assert result.losses_on(enhanced, samples) == pytest.approx(result.losses, rel=1e-4)


@pytest.mark.parametrize("materials, jobs", [(5, 2), (7, 3), (2, 4), (1, 1), (6, 1)])
def test_shares_are_consecutive_runs_of_nearly_equal_size(materials, jobs):
    parts = shares(materials, jobs)
    assert [i for part in parts for i in part] == list(range(materials))
    assert len(parts) == min(jobs, materials) and all(parts)
    assert max(map(len, parts)) - min(map(len, parts)) <= 1


def test_shares_need_one_job():
    with pytest.raises(ValueError, match="jobs must be at least 1"):
        shares(3, 0)


def test_one_job_is_fit_materials_itself(two_zoo_materials):
    """``fit_in_processes`` with one job (or one material) fits here, as ``fit_materials`` does; the
    split over processes is checked end to end by ``neuenh fit --jobs`` (tests/cli/test_fit_cli.py)."""
    model = get_model("ggx")
    protocol = PlainLBFGS(iterations=5, warmup_epochs=5)
    single = fit_in_processes(model, two_zoo_materials, protocol, 1)
    assert single.losses == fit_materials(model, two_zoo_materials, protocol).losses
    assert "processes" not in single.protocol
    assert fit_in_processes(model, two_zoo_materials.select([1]), protocol, 4).losses == \
        fit_materials(model, two_zoo_materials.select([1]), protocol).losses


@pytest.mark.parametrize("counts, block_samples, want", [
    ([3, 3, 3], 6, [[0, 1], [2]]),
    ([10, 1, 1], 5, [[0], [1, 2]]),  # a material over the block is a block of its own
    ([2, 9, 2], 9, [[0], [1], [2]]),
    ([1, 1, 1, 1], 100, [[0, 1, 2, 3]]),
    ([1, 1, 1, 4], 12, [[0, 1, 2], [3]]),  # padded to 4 slots the four would take 16
    ([4, 1, 1], 12, [[0, 1, 2]]),  # each padded to 4: 12
])
def test_blocks_are_consecutive_runs_whose_padded_batch_holds_at_most_the_block_samples(counts, block_samples, want):
    assert blocks(counts, block_samples) == want


def test_a_fit_in_blocks_is_each_blocks_own_fit_joined_in_order(enhanced):
    """``fit_materials`` fits consecutive blocks of at most ``block_samples`` samples, each as the
    protocol fits those materials alone (their part of ``start`` too), and joins them in order; a fit
    of one block is the protocol's fit itself."""
    samples = sample_materials(synthetic_zoo(3, seed=8), 150, seed=2)
    protocol = LatentAdam(epochs=5)
    start = protocol.fit(enhanced, samples).materials
    for given in (None, start):
        done = []
        blocked = fit_materials(enhanced, samples, protocol, start=given, block_samples=300,
                                progress=lambda n, total: done.append((n, total)))
        parts = [protocol.fit(enhanced, samples.select(b), start=None if given is None else given.subset(b))
                 for b in ([0, 1], [2])]
        assert blocked.losses == parts[0].losses + parts[1].losses and blocked.protocol["blocks"] == 2
        assert torch.equal(blocked.materials.latent, torch.cat([p.materials.latent for p in parts]))
        assert blocked.materials.names == samples.names and done == [(2, 3), (3, 3)]
    whole = fit_materials(enhanced, samples, protocol)
    assert whole.losses == protocol.fit(enhanced, samples).losses and "blocks" not in whole.protocol

    class SmallBlocks(LatentAdam):  # the block's size is the protocol's unless the call gives one
        block_samples = 300

    own = fit_materials(enhanced, samples, SmallBlocks(epochs=5))
    assert own.protocol["blocks"] == 2 and own.losses == fit_materials(enhanced, samples, protocol, block_samples=300).losses
    with pytest.raises(ValueError, match="block_samples must be at least 1"):
        fit_materials(enhanced, samples, protocol, block_samples=0)
