"""``BRDFModel.forward_indexed`` (the training and fitting path: per-material work done once per
material) against ``forward`` on per-sample gathered parameters (the reference path).

In float64 the two are the same function, so values and every gradient (per-material parameters,
latent, module weights) agree to rounding, on every row of the stability grid (grazing, below the
horizon, roughness 1e-4..1, f0 0 and 1) for every model in its analytical state, with every
position neural and (GGX) in the paper's state; in float32, as training runs it, values and
gradients are finite on the grid.
"""

from __future__ import annotations

import copy

import pytest
import torch

from neuenh.models import available_models, get_model
from neuenh.rows import RowGrid
from test_models import assert_finite_grads, stability_grid
from ggx_states import PAPER_STATE


def states(name: str) -> list[str]:
    n = len(get_model(name).positions)
    return ["0" * n, "1" * n] + ([PAPER_STATE] if name == "ggx" else [])


CASES = [(m, s) for m in available_models() for s in states(m)]


def grid_table(model, dtype):
    """The stability grid as a material table (its distinct parameter rows, as leaves) and the
    material index of each direction pair; latent codes differ per material."""
    wi, wo, _, params = stability_grid(model)
    keys = torch.cat([torch.as_tensor(params[k]) for k in sorted(params)], dim=1)
    unique, material = torch.unique(keys, dim=0, return_inverse=True)
    first = torch.stack([torch.nonzero(material == j)[0, 0] for j in range(len(unique))])
    values = {k: torch.as_tensor(v)[first].to(dtype).requires_grad_(True) for k, v in params.items()}
    generator = torch.Generator().manual_seed(0)
    latent = torch.rand(len(unique), model.latent_dim, generator=generator, dtype=torch.float64)
    latent = latent.to(dtype).requires_grad_(True)
    return torch.as_tensor(wi, dtype=dtype), torch.as_tensor(wo, dtype=dtype), values, latent, material


def as_grid(wi, wo, material):
    """The same samples regrouped as a ``RowGrid``: each material's first ``slots`` samples (the
    fewest any material has), material by material; returns wi, wo, the grid and each sample's row."""
    slots = int(torch.bincount(material).min())
    order = torch.cat([torch.nonzero(material == j)[:slots, 0] for j in range(int(material.max()) + 1)])
    return wi[order], wo[order], RowGrid(int(material.max()) + 1, slots), material[order]


def value_and_grads(model, f, values, latent):
    loss = (torch.log1p(f.abs()) * torch.linspace(0.5, 1.5, f.numel(), dtype=f.dtype).reshape(f.shape)).sum()
    leaves = [*values.values(), latent, *model.neural.parameters()]
    return f.detach(), torch.autograd.grad(loss, leaves, allow_unused=True)


@pytest.mark.parametrize("rows", ["index", "grid"])
@pytest.mark.parametrize("name, state", CASES, ids=[f"{m}-{s}" for m, s in CASES])
def test_forward_indexed_equals_forward_on_gathered_parameters(name, state, rows):
    """Rows given as an index (any order) or as a grid (consecutive runs: a fit's layout)."""
    model = copy.deepcopy(get_model(name, state=state, seed=2)).double()
    wi, wo, values, latent, material = grid_table(model, torch.float64)
    assert 9 <= len(latent) < len(wi)  # several materials, each on several rows
    given = material
    if rows == "grid":
        wi, wo, given, material = as_grid(wi, wo, material)
        assert given.slots >= 2
    gathered = {k: v[material] for k, v in values.items()}
    want, want_grads = value_and_grads(model, model.forward(wi, wo, gathered, latent[material]), values, latent)
    got, got_grads = value_and_grads(model, model.forward_indexed(wi, wo, values, latent, given), values, latent)
    scale = want.abs().max()
    assert torch.allclose(got, want, rtol=1e-12, atol=1e-13 * scale)
    for g, w in zip(got_grads, want_grads):
        if w is None:
            assert g is None or not g.any()
            continue
        assert torch.allclose(g, w, rtol=1e-9, atol=1e-11 * w.abs().max().clamp_min(1.0))


@pytest.mark.parametrize("name, state", CASES, ids=[f"{m}-{s}" for m, s in CASES])
def test_forward_indexed_is_finite_in_float32(name, state):
    model = get_model(name, state=state, seed=2)
    wi, wo, values, latent, material = grid_table(model, torch.float32)
    f = model.forward_indexed(wi, wo, values, latent, material)
    assert torch.isfinite(f).all()
    f.abs().log1p().sum().backward()
    assert_finite_grads([(k, v) for k, v in values.items() if k in model.param_names], f"{name} values")
    if model.uses_latent:
        assert_finite_grads([("latent", latent)], f"{name} latent")
    assert_finite_grads(model.neural.named_parameters(), f"{name} modules")
