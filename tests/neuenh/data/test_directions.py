import math

import pytest
import torch

from neuenh.data.directions import from_rusinkiewicz, sample_directions, to_rusinkiewicz


def _angles(n, seed):
    g = torch.Generator().manual_seed(seed)
    u = torch.rand(n, 4, generator=g, dtype=torch.float64)
    # Stay away from the poles of the parameterisation, where phi is undefined.
    return (0.01 + u[:, 0] * 1.5, u[:, 1] * 2 * math.pi - math.pi, 0.01 + u[:, 2] * 1.5,
            u[:, 3] * 2 * math.pi - math.pi)


def test_half_and_difference_vectors_match_the_definition():
    th, ph, td, pd = _angles(2000, 0)
    wi, wo = from_rusinkiewicz(th, ph, td, pd)
    assert torch.allclose(wi.norm(dim=1), torch.ones(2000, dtype=torch.float64))
    assert torch.allclose(wo.norm(dim=1), torch.ones(2000, dtype=torch.float64))
    h = (wi + wo) / (wi + wo).norm(dim=1, keepdim=True)
    expected_h = torch.stack([th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()], 1)
    assert torch.allclose(h, expected_h, atol=1e-10)
    # theta_d is the angle between wi and h (Rusinkiewicz 1998, Fig. 2).
    assert torch.allclose((wi * h).sum(1), td.cos(), atol=1e-10)


def test_round_trip_through_angles():
    angles = _angles(2000, 1)
    back = to_rusinkiewicz(*from_rusinkiewicz(*angles))
    for a, b in zip(angles, back):
        diff = torch.remainder(a - b + math.pi, 2 * math.pi) - math.pi
        assert diff.abs().max() < 1e-8


@pytest.mark.parametrize("anisotropic", [True, False])
def test_samples_are_above_the_horizon_and_reproducible(anisotropic):
    wi, wo = sample_directions(5000, seed=3, anisotropic=anisotropic)
    assert wi.shape == wo.shape == (5000, 3)
    assert (wi[:, 2] > 0).all() and (wo[:, 2] > 0).all()
    wi2, wo2 = sample_directions(5000, seed=3, anisotropic=anisotropic)
    assert torch.equal(wi, wi2) and torch.equal(wo, wo2)
    assert not torch.equal(wi, sample_directions(5000, seed=4, anisotropic=anisotropic)[0])


def test_isotropic_samples_keep_the_half_vector_in_the_xz_plane():
    wi, wo = sample_directions(3000, seed=0, anisotropic=False)
    h = wi + wo
    assert h[:, 1].abs().max() < 1e-9


def test_theta_h_is_uniform_among_accepted_pairs_near_the_peak():
    # Pairs with small theta_d are never rejected, so theta_h stays uniform on [0, pi/2 - theta_d].
    wi, wo = sample_directions(200_000, seed=5)
    th, _, td, _ = to_rusinkiewicz(wi, wo)
    sel = th[td < 0.1]
    hist = torch.histc(sel[sel < 1.4], bins=7, min=0, max=1.4)
    assert (hist / hist.mean() - 1).abs().max() < 0.1
