"""Graphs, states and candidates (item 5 of the core issue)."""

import pytest
import torch

from neuenh.models import available_models, get_model
from neuenh.modules import ModuleConfig
from ggx_states import GGX_POSITIONS, PAPER_STATE



def test_ggx_graph_is_the_papers():
    ggx = get_model("ggx")
    assert ggx.positions == GGX_POSITIONS
    assert ggx.describe() == "M + ((((S * D) * F) * G) * invE)"
    enhanced = get_model("ggx", state=PAPER_STATE)
    assert enhanced.describe() == "M + ((((S * D) * F^) *^ G^) * invE^)"


def test_module_input_widths_follow_the_paper():
    model = get_model("ggx", state="11111111111")
    widths = {p: (m.in_features, m.out_features) for p, m in model.neural.items()}
    assert widths["D"] == (45, 1)  # 12 analytical + 27 latent + wi, wo
    assert widths["M"] == (39, 3) and widths["S"] == (39, 3)  # no directions
    assert widths["S*D"] == (4, 3)  # operands: S (3) and D (1)
    assert widths["M+S*D*F*G*invE"] == (6, 3)
    assert model.neural["D"].hidden == (16, 32, 16)


def test_paper_state_has_about_seven_thousand_weights():
    assert 6000 < get_model("ggx", state=PAPER_STATE).n_weights() < 8000


@pytest.mark.parametrize("name", available_models())
def test_all_zero_state_has_no_modules(name):
    model = get_model(name)
    assert model.state == "0" * len(model.positions) and len(model.neural) == 0


def test_m_ary_digits_select_another_width():
    config = ModuleConfig(choices=((16, 32, 16), (8, 8)))
    model = get_model("ggx", state="00200000000", module_config=config)
    assert model.neural["D"].hidden == (8, 8)
    with pytest.raises(ValueError, match="digit '3' at position D"):
        get_model("ggx", state="00300000000", module_config=config)


def test_candidate_keeps_shared_modules_adds_fresh_ones_and_drops_reverted():
    parent = get_model("ggx", state="00011000000", seed=1)
    with torch.no_grad():
        for p in parent.parameters():
            p.add_(0.25)  # "trained": differs from any fresh initialisation
    child = parent.enhance("00010100000", seed=7)
    assert set(child.neural) == {"F", "invE"}
    for key, value in parent.neural["F"].state_dict().items():
        assert torch.equal(child.neural["F"].state_dict()[key], value)
    # A copy, not a shared module: training the child leaves the parent alone.
    assert child.neural["F"].layers[0].weight.data_ptr() != parent.neural["F"].layers[0].weight.data_ptr()
    fresh = get_model("ggx", state="00000100000", seed=7).neural["invE"]
    for key, value in fresh.state_dict().items():
        assert torch.equal(child.neural["invE"].state_dict()[key], value)


def test_fresh_modules_depend_on_seed_and_position():
    a = get_model("ggx", state="00011000000", seed=3)
    b = get_model("ggx", state="00011000000", seed=3)
    c = get_model("ggx", state="00011000000", seed=4)
    w = lambda m, p: m.neural[p].layers[0].weight  # noqa: E731
    assert torch.equal(w(a, "F"), w(b, "F"))
    assert not torch.equal(w(a, "F"), w(c, "F"))
    assert not torch.equal(w(a, "F"), w(a, "G"))


def test_xavier_initialisation_bounds():
    layer = get_model("ggx", state="00100000000").neural["D"].layers[0]
    bound = (6 / (45 + 16)) ** 0.5
    assert layer.weight.abs().max() <= bound and layer.weight.abs().max() > 0.5 * bound
    assert torch.equal(layer.bias, torch.zeros(16))


def test_enhanced_model_refuses_states_it_holds_no_module_for():
    model = get_model("ggx", state=PAPER_STATE)
    with pytest.raises(ValueError, match="module 1 at D"):
        model._held_digits("00100000000")
    assert model._held_digits("00010000000") == (0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0)


def test_a_model_without_latent_parameters_needs_no_latent():
    model = get_model("ggx", state="00100000000", latent_dim=0)
    assert model.neural["D"].in_features == 12 + 6
    wi = torch.tensor([[0.0, 0.6, 0.8]])
    wo = torch.tensor([[0.0, -0.6, 0.8]])
    params = {s.name: torch.full((s.width,), s.init) for s in model.specs}
    assert torch.isfinite(model.evaluate(wi, wo, params)).all()
