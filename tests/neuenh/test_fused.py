"""Fused neural modules: ``run_modules`` in its fused modes against the per-module loop.

The fused paths (one wide matmul for the first layers; batched matmuls or module-by-module layers
after it) must give the loop's outputs and gradients up to float32 rounding, whatever the modules'
shapes, so fusion can be switched on wherever it measures faster (docs/BENCHMARKS.md).
"""

import pytest
import torch

import neuenh.modules as modules_mod
from neuenh.data.sampling import sample_directions
from neuenh.models import get_model
from neuenh.modules import NeuralModule, _run_modules_unfused, fusion, run_modules

PAPER_STATE = "00011100100"  # F, G, invE and the x of (S*D*F) x G are neural
RTOL, ATOL = 1e-5, 1e-6
FUSED_MODES = ("batched", "first_layer")


def assert_grad_close(actual, expected, name=""):
    """Gradients sum over the batch in another order when fused; elements that cancel in that
    sum get an absolute tolerance at float32 rounding of the gradient's scale."""
    atol = max(ATOL, RTOL * float(expected.abs().max()))
    torch.testing.assert_close(actual, expected, rtol=RTOL, atol=atol, msg=lambda m: f"{name}: {m}")


def make_modules(specs, in_features=45, seed=0):
    """Modules from (hidden, out_features, negative_slope) triples, with non-zero biases (a fresh
    module's are zero, which would hide a bias mix-up)."""
    g = torch.Generator().manual_seed(seed)
    out = []
    for hidden, width, slope in specs:
        module = NeuralModule(in_features, width, hidden, slope, g)
        with torch.no_grad():
            for layer in module.layers:
                layer.bias.uniform_(-0.5, 0.5, generator=g)
        out.append(module)
    return out


def fused_run(mode):
    def run(modules, x):
        with fusion(mode):
            return run_modules(modules, x)
    return run


PAPER = ((16, 32, 16), 1, 0.01)
CASES = {
    "equal widths (the paper's F, G, invE)": [PAPER] * 3,
    "two equal": [PAPER, PAPER],
    "mismatched hidden widths": [PAPER, ((8, 8), 1, 0.01), ((16, 32, 16), 1, 0.01)],
    "mismatched depth": [((16,), 1, 0.01), PAPER, ((32, 16), 1, 0.01)],
    "mismatched output widths": [PAPER, ((16, 32, 16), 3, 0.01)],
    "mismatched slopes": [PAPER, ((16, 32, 16), 1, 0.2)],
    "no hidden layer": [((), 1, 0.01), PAPER],
}


def outputs_and_grads(modules, x, run, upstream):
    for p in (*[q for m in modules for q in m.parameters()], x):
        p.grad = None
    outs = run(modules, x)
    sum((o * u).sum() for o, u in zip(outs, upstream)).backward()
    grads = [p.grad.clone() for m in modules for p in m.parameters()]
    return [o.detach() for o in outs], grads, x.grad.clone()


@pytest.mark.parametrize("mode", FUSED_MODES)
@pytest.mark.parametrize("case", CASES)
def test_fused_outputs_and_gradients_match_the_loop(case, mode):
    modules = make_modules(CASES[case])
    g = torch.Generator().manual_seed(1)
    x = torch.randn(1000, 45, generator=g).requires_grad_(True)
    upstream = [torch.randn(1000, m.out_features, generator=g) for m in modules]
    fused = outputs_and_grads(modules, x, fused_run(mode), upstream)
    loop = outputs_and_grads(modules, x, _run_modules_unfused, upstream)
    for out_f, out_l, m in zip(fused[0], loop[0], modules):
        assert out_f.shape == out_l.shape == (1000, m.out_features)
        torch.testing.assert_close(out_f, out_l, rtol=RTOL, atol=ATOL)
    names = [f"module {i} {n}" for i, m in enumerate(modules) for n, _ in m.named_parameters()]
    for name, grad_f, grad_l in zip(names, fused[1], loop[1]):
        assert_grad_close(grad_f, grad_l, name)
    assert_grad_close(fused[2], loop[2], "input")


def test_modes_choose_the_path(monkeypatch):
    calls = []
    real = modules_mod._run_modules_fused

    def spy(ms, x, batched=True):
        calls.append((len(ms), batched))
        return real(ms, x, batched)

    monkeypatch.setattr(modules_mod, "_run_modules_fused", spy)
    model = get_model("ggx", state=PAPER_STATE)
    paper = [model.neural[p] for p in ("F", "G", "invE")]
    assert modules_mod._same_later_layers(paper)
    x = torch.rand(10, 45)
    run_modules(paper, x)  # the default: the loop
    with fusion(True):
        run_modules(paper, x)
        run_modules(paper[:1], x)  # a single module never fuses
        with fusion(False):
            run_modules(paper, x)
    with fusion("first_layer"):
        run_modules(paper, x)
    assert calls == [(3, True), (3, False)]
    with pytest.raises(ValueError, match="fusion mode"):
        with fusion("fast"):
            pass


@pytest.mark.parametrize("mode", FUSED_MODES)
@pytest.mark.parametrize("shape", [(0, 45), (1, 45), (45,), (2, 5, 45)])
def test_fused_handles_any_batch_shape(shape, mode):
    modules = make_modules([PAPER] * 3)
    x = torch.randn(shape, generator=torch.Generator().manual_seed(2))
    for out_f, out_l in zip(fused_run(mode)(modules, x), _run_modules_unfused(modules, x)):
        assert out_f.shape == out_l.shape
        torch.testing.assert_close(out_f, out_l, rtol=RTOL, atol=ATOL)


@pytest.mark.parametrize("module_dtype, input_dtype",
                         [(torch.float32, torch.float64), (torch.float64, torch.float32)])
def test_fused_keeps_the_dtype_rules(module_dtype, input_dtype):
    """Input cast to the weights' dtype, output cast back to the input's, as NeuralModule.forward."""
    modules = [m.to(module_dtype) for m in make_modules([PAPER] * 3)]
    x = torch.randn(100, 45, dtype=input_dtype, generator=torch.Generator().manual_seed(3))
    for out_f, out_l in zip(fused_run(True)(modules, x), _run_modules_unfused(modules, x)):
        assert out_f.dtype == out_l.dtype == input_dtype
        torch.testing.assert_close(out_f, out_l, rtol=RTOL, atol=ATOL)


def test_mixed_dtypes_fall_back_to_the_loop():
    modules = make_modules([PAPER] * 2)
    modules[1].double()
    x = torch.randn(10, 45)
    for out_f, out_l in zip(fused_run(True)(modules, x), _run_modules_unfused(modules, x)):
        assert torch.equal(out_f, out_l)


def paper_model_and_inputs(n=2000):
    model = get_model("ggx", state=PAPER_STATE, seed=3)
    g = torch.Generator().manual_seed(4)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.1 * torch.randn(p.shape, generator=g))  # "trained": non-zero biases
    wi, wo = sample_directions(n, seed=5, dtype=torch.float32)
    params = {s.name: s.from_unit(0.1 + 0.8 * torch.rand(n, s.width, generator=g)) for s in model.specs}
    params["latent"] = torch.rand(n, model.latent_dim, generator=g)
    return model, wi, wo, params


@pytest.mark.parametrize("mode", FUSED_MODES)
def test_paper_state_evaluates_the_same_fused_or_not(mode):
    model, wi, wo, params = paper_model_and_inputs()
    with torch.no_grad():
        loop = model.evaluate(wi, wo, params)
        with fusion(mode):
            fused = model.evaluate(wi, wo, params)
    assert fused.shape == (len(wi), 3) and torch.isfinite(fused).all()
    assert (fused > 0).any()
    torch.testing.assert_close(fused, loop, rtol=RTOL, atol=ATOL)


@pytest.mark.parametrize("mode", FUSED_MODES)
def test_paper_state_trains_the_same_fused_or_not(mode):
    """Gradients of a training step reach every module weight and the latent alike."""
    model, wi, wo, params = paper_model_and_inputs()
    latent = params.pop("latent").requires_grad_(True)

    def grads():
        model.zero_grad(set_to_none=True)
        latent.grad = None
        model.forward(wi, wo, params, latent).log1p().mean().backward()
        return {n: p.grad.clone() for n, p in model.named_parameters()}, latent.grad.clone()

    loop, loop_latent = grads()
    with fusion(mode):
        fused, fused_latent = grads()
    assert set(fused) == set(loop) == {n for n, _ in model.named_parameters()}
    for name in fused:
        assert_grad_close(fused[name], loop[name], name)
    assert_grad_close(fused_latent, loop_latent, "latent")
