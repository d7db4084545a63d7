import math

import numpy as np
import pytest
import torch

from neuenh.data.directions import (MIRROR_DEG, Sampling, from_rusinkiewicz, near_mirror_mask, sample_directions,
                                    to_rusinkiewicz)


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


@pytest.mark.parametrize("share", [0.0, 0.25, 0.5, 1.0])
def test_a_share_of_pairs_is_drawn_near_the_mirror_direction(share):
    wi, wo = sample_directions(4000, seed=7, near_mirror=share)
    assert wi.shape == wo.shape == (4000, 3) and (wi[:, 2] > 0).all() and (wo[:, 2] > 0).all()
    # theta_h from an independent derivation: the angle of the normalised half vector to z.
    h = (wi + wo).numpy()
    theta_h = np.degrees(np.arccos(h[:, 2] / np.linalg.norm(h, axis=1)))
    near = int(round(4000 * share))
    assert (theta_h[4000 - near:] <= MIRROR_DEG + 1e-9).all()  # the near-mirror rows come last
    # the other rows are Rusinkiewicz-uniform: as often below 10 degrees as a draw without the share
    # (about 1/6: 1/9 of theta_h, raised by rejecting the pairs below the horizon, most at large theta_h)
    if near < 4000:
        h0 = (lambda wi, wo: (wi + wo).numpy())(*sample_directions(20_000, seed=8))
        expected = (np.degrees(np.arccos(h0[:, 2] / np.linalg.norm(h0, axis=1))) <= MIRROR_DEG).mean()
        assert 0.12 < expected < 0.22
        assert abs((theta_h[: 4000 - near] <= MIRROR_DEG).mean() - expected) < 0.03
    assert torch.equal(near_mirror_mask(wi, wo), torch.as_tensor(theta_h <= MIRROR_DEG))


def test_sampling_draws_isotropic_materials_over_every_azimuth_when_asked():
    at_zero = Sampling().directions(2000, seed=1, isotropic=True)
    every = Sampling(every_azimuth=True).directions(2000, seed=1, isotropic=True)
    assert (at_zero[0] + at_zero[1])[:, 1].abs().max() < 1e-9  # phi_h = 0: h in the xz plane
    phi_h = torch.atan2(*(every[0] + every[1])[:, [1, 0]].T)
    assert torch.histc(phi_h, bins=8, min=-math.pi, max=math.pi).min() > 2000 / 8 * 0.8
    # an anisotropic material draws every azimuth whatever the flag says
    assert torch.equal(Sampling().directions(100, seed=2, isotropic=False)[0], sample_directions(100, seed=2)[0])


@pytest.mark.parametrize("bad", [-0.1, 1.5])
def test_a_share_outside_0_1_is_refused(bad):
    with pytest.raises(ValueError, match="near_mirror is a share"):
        Sampling(near_mirror=bad)
    with pytest.raises(ValueError, match="near_mirror is a share"):
        sample_directions(10, seed=0, near_mirror=bad)
