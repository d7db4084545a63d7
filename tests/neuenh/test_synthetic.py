import math

import pytest
import torch

from neuenh.data.samples import Samples, sample_materials
from neuenh.data.synthetic import (
    CONDUCTORS,
    ZOO_FAMILIES,
    dielectric_fresnel,
    synthetic_ggx,
    synthetic_zoo,
)
from neuenh.models import get_model
from neuenh.models.alternatives import conductor_fresnel
from neuenh.ops import TORCH

ZOO = synthetic_zoo(len(ZOO_FAMILIES), seed=11)


def _uniform_hemisphere(n, seed):
    g = torch.Generator().manual_seed(seed)
    u = torch.rand(n, 2, generator=g, dtype=torch.float64)
    r = torch.sqrt(1 - u[:, 0] ** 2)
    phi = 2 * math.pi * u[:, 1]
    return torch.stack([r * phi.cos(), r * phi.sin(), u[:, 0]], 1)


@pytest.mark.parametrize("material", ZOO, ids=[m.name for m in ZOO])
def test_zoo_materials_are_reciprocal_finite_and_non_negative(material):
    wi, wo = _uniform_hemisphere(4000, 0), _uniform_hemisphere(4000, 1)
    f = material.evaluate(wi, wo)
    assert torch.isfinite(f).all() and (f >= 0).all()
    assert torch.allclose(f, material.evaluate(wo, wi), rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("material", ZOO, ids=[m.name for m in ZOO])
@pytest.mark.parametrize("theta_i", [0.0, 45.0, 70.0])
def test_zoo_materials_conserve_energy(material, theta_i):
    """Directional albedo (Monte Carlo over the hemisphere) stays below 1."""
    n = 200_000
    wo = _uniform_hemisphere(n, 2)
    t = math.radians(theta_i)
    wi = torch.tensor([[math.sin(t), 0.0, math.cos(t)]], dtype=torch.float64).expand(n, 3)
    albedo = (material.evaluate(wi, wo) * wo[:, 2:3]).mean(0) * 2 * math.pi
    assert (albedo < 1.0).all(), albedo


def test_zoo_is_seeded_and_covers_every_family():
    a, b = synthetic_zoo(12, seed=4), synthetic_zoo(12, seed=4)
    assert [m.name for m in a] == [m.name for m in b]
    assert {m.metadata["family"] for m in a} == set(ZOO_FAMILIES)
    wi, wo, f = a[0].samples(100, seed=1)
    assert torch.equal(f, b[0].samples(100, seed=1)[2])


def test_conductor_fresnel_closed_forms():
    eta, k = (torch.tensor(v, dtype=torch.float64) for v in CONDUCTORS["gold"])
    normal = conductor_fresnel(TORCH, torch.ones(1, 1, dtype=torch.float64), eta, k)
    assert torch.allclose(normal, ((eta - 1) ** 2 + k**2) / ((eta + 1) ** 2 + k**2), rtol=1e-12)
    grazing = conductor_fresnel(TORCH, torch.full((1, 1), 1e-6, dtype=torch.float64), eta, k)
    assert torch.allclose(grazing, torch.ones(3, dtype=torch.float64), atol=1e-4)
    # k -> 0 is a dielectric.
    dielectric = conductor_fresnel(TORCH, torch.full((1, 1), 0.6, dtype=torch.float64),
                                   torch.tensor([1.5], dtype=torch.float64), torch.zeros(1, dtype=torch.float64))
    assert torch.allclose(dielectric, dielectric_fresnel(torch.full((1, 1), 0.6, dtype=torch.float64), 1.5))


def test_dielectric_fresnel_at_normal_incidence():
    f = dielectric_fresnel(torch.ones(1, dtype=torch.float64), 1.5)
    assert float(f) == pytest.approx(((1.5 - 1) / (1.5 + 1)) ** 2, rel=1e-12)


def test_synthetic_ggx_is_ggx_with_multiplicative_noise():
    (material,) = synthetic_ggx(1, seed=3)
    wi, wo, noisy = material.samples(20_000, seed=0)
    params = {k: torch.tensor(v, dtype=torch.float64) for k, v in material.metadata["params"].items()}
    clean = get_model("ggx").evaluate(wi, wo, params)
    ratio = (noisy / clean)[clean > 1e-6]
    assert ratio.mean().item() == pytest.approx(1.0, abs=0.01)
    assert ratio.std().item() == pytest.approx(0.1, abs=0.01)


def test_sample_sets_split_per_material():
    samples = sample_materials(synthetic_zoo(3, seed=0), 1000, seed=0)
    assert isinstance(samples, Samples) and len(samples) == 3000
    train, val = samples.split(0.2, seed=1)
    assert len(val) == 600 and len(train) == 2400
    assert torch.bincount(val.material).tolist() == [200, 200, 200]
    again = samples.split(0.2, seed=1)[1]
    assert torch.equal(val.wi, again.wi)


def test_at_most_draws_only_from_materials_over_the_cap():
    samples = Samples.concat([sample_materials(synthetic_zoo(1, seed=s), n, seed=s) for s, n in ((0, 50), (1, 300))])
    assert samples.counts().tolist() == [50, 300]
    assert samples.at_most(300, seed=0) is samples  # no material over the cap: the same rows, no copy
    capped = samples.at_most(120, seed=4)
    assert torch.bincount(capped.material).tolist() == [50, 120]
    assert torch.equal(capped.of_material(0).wi, samples.of_material(0).wi)  # under the cap: every row
    # the capped material's rows are its own (matched by their f_r), distinct and in their order
    own = samples.of_material(1).f_r
    where = [int(torch.nonzero((own == row).all(1))[0]) for row in capped.of_material(1).f_r]
    assert len(set(where)) == 120 and where == sorted(where)
    assert torch.equal(samples.at_most(120, seed=4).wi, capped.wi)  # seeded
    assert not torch.equal(samples.at_most(120, seed=5).wi, capped.wi)
    with pytest.raises(ValueError, match="n >= 1"):
        samples.at_most(0, seed=0)
