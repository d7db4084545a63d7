"""The NBRDF baseline fitted per material, against the published networks' own forward pass."""

import numpy as np
import pytest
import torch

from neuenh.data.nbrdf import NBRDFMaterial
from neuenh.data.samples import sample_materials
from neuenh.study.nbrdf_fit import NBRDFConfig, NBRDFNetwork, fit_nbrdf
from neuenh.train import log_l1


def _teacher(seed: int) -> NBRDFMaterial:
    """A 6-21-21-3 network with random weights, evaluated by the data reader's float64 forward."""
    rng = np.random.default_rng(seed)
    shapes = {"W1": (6, 21), "b1": (21,), "W2": (21, 21), "b2": (21,), "W3": (21, 3), "b3": (3,)}
    weights = {k: rng.normal(0, 0.4, s).astype(np.float32) for k, s in shapes.items()}
    weights["W3"] *= 0.3
    weights["b3"] = np.full(3, 0.5, np.float32)  # positive f_r of a plausible scale
    return NBRDFMaterial(f"teacher{seed}", weights)


def test_the_network_is_the_published_architecture():
    teacher = _teacher(0)
    net = NBRDFNetwork()
    with torch.no_grad():
        for layer, (w, b) in zip([net.layers[0], net.layers[2], net.layers[4]], [("W1", "b1"), ("W2", "b2"), ("W3", "b3")]):
            layer.weight.copy_(torch.from_numpy(teacher.weights[w]).T)
            layer.bias.copy_(torch.from_numpy(teacher.weights[b]))
    wi, wo, want = teacher.samples(2000, seed=3)
    got = net.evaluate(wi.float(), wo.float())
    np.testing.assert_allclose(got.numpy(), want.numpy(), rtol=2e-3, atol=1e-5)  # float32 against float64
    assert net.n_weights() == 6 * 21 + 21 + 21 * 21 + 21 + 21 * 3 + 3 == 675


def test_fitting_recovers_a_network_of_the_same_architecture():
    teachers = [_teacher(1), _teacher(2)]
    fit = sample_materials(teachers, 4000, seed=0)
    test = sample_materials(teachers, 4000, seed=1)
    result = fit_nbrdf(fit, NBRDFConfig(epochs=60))
    for m, net in enumerate(result.networks):
        net.requires_grad_(False)
        rows = test.material == m
        untrained = log_l1(NBRDFNetwork(seed=m).requires_grad_(False)(test.wi[rows], test.wo[rows]), test.f_r[rows], test.wi[rows]).mean()
        heldout = log_l1(net(test.wi[rows], test.wo[rows]), test.f_r[rows], test.wi[rows]).mean()
        assert heldout < 0.1 * untrained and heldout < 0.02
        assert result.losses[m] == pytest.approx(float(heldout), rel=0.5)


def test_below_the_horizon_is_zero_and_grazing_is_finite():
    net = NBRDFNetwork(seed=4)
    wi = torch.tensor([[0.0, 0.6, -0.8], [1.0, 0.0, 1e-7], [0.0, 0.0, 1.0]])
    wo = torch.tensor([[0.0, 0.0, 1.0], [-1.0, 0.0, 1e-7], [0.0, 0.6, -0.8]])
    f = net.evaluate(wi, wo)
    assert torch.isfinite(f).all() and (f[0] == 0).all() and (f[2] == 0).all()
