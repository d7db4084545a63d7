import math

import pytest
import torch

from neuenh.models import available_models, get_model

SPECS = [(name, spec) for name in available_models() for spec in get_model(name).specs]
IDS = [f"{name}.{spec.name}" for name, spec in SPECS]


@pytest.mark.parametrize("model,spec", SPECS, ids=IDS)
def test_raw_values_never_leave_the_range(model, spec):
    raw = torch.tensor([-1e30, -1e4, -50.0, -1.0, 0.0, 1.0, 50.0, 1e4, 1e30])
    value = spec.from_raw(raw)
    assert torch.isfinite(value).all()
    assert (value >= spec.low).all() and (value <= spec.high).all()


@pytest.mark.parametrize("model,spec", SPECS, ids=IDS)
def test_mapping_round_trips_inside_the_range(model, spec):
    unit = torch.linspace(0.01, 0.99, 33, dtype=torch.float64)
    value = spec.from_unit(unit)
    assert torch.allclose(spec.from_raw(spec.to_raw(value)), value, rtol=1e-9, atol=1e-12)
    assert torch.allclose(spec.to_unit(value), unit, atol=1e-12)


def test_ggx_has_the_papers_twelve_parameters():
    specs = get_model("ggx").specs
    assert specs.names == ("normal", "t_theta", "rho_d", "rho_s", "alpha_x", "alpha_y", "f0")
    assert specs.total_width == 12
    # The mean of the normal and tangent ranges is the geometric frame itself.
    assert specs["normal"].init == 0.0 and specs["t_theta"].init == 0.0


def test_log_scale_gradient_is_finite_at_tiny_roughness():
    spec = get_model("ggx").specs["alpha_x"]
    raw = spec.to_raw(torch.tensor([1e-4, 1.0], dtype=torch.float64)).requires_grad_()
    spec.from_raw(raw).sum().backward()
    assert torch.isfinite(raw.grad).all()
    assert math.isclose(float(spec.from_raw(raw.detach())[0]), 1e-4, rel_tol=1e-6)


def test_scalars_broadcast_to_the_parameter_width():
    ggx = get_model("ggx")
    wi = torch.tensor([[0.0, 0.6, 0.8]])
    wo = torch.tensor([[0.0, -0.6, 0.8]])
    base = {s.name: torch.full((s.width,), s.init) for s in ggx.specs}
    scalar = {**base, "rho_d": torch.tensor(0.5), "rho_s": torch.tensor([0.5])}
    assert torch.equal(ggx.evaluate(wi, wo, scalar), ggx.evaluate(wi, wo, base))
