"""Alternative analytical terms (``neuenh.models.alternatives``): the m-ary digits that choose among
the original term, its neural modules and other formulas. In layers, as test_models:

1. each alternative against an independent numpy derivation from its paper (``reference_brdfs``);
2. closed forms: every D integrates to 1 over projected area; the limits where an alternative is
   the original (γ = 2, tint 1, χ = 0, σ = 0, κ = 0 is a dielectric);
3. stability: the hard-case grid gives finite values, zero below, finite gradients;
4. the model's contract: choices by name, per-position digit counts, parameters a state uses,
   specialize and the numpy backend equal evaluate, bundles round-trip, a search's Hamming ball.
"""

from __future__ import annotations

import math
import zlib

import numpy as np
import pytest
import torch

from neuenh.checkpoint import Bundle
from neuenh.data.synthetic import dielectric_fresnel
from neuenh.graph import Term
from neuenh.materials import MaterialParams, MaterialTable
from neuenh.models import get_model
from neuenh.ops import NUMPY, TORCH
from neuenh.search import Constraints, hamming_ball
from neuenh.shading import COS_EPS, make_shading

import reference_brdfs as ref

MODEL = get_model("ggx", alternatives=True)
K = MODEL.module_config.digits  # alternatives start at this digit
#: (position, choice) of every alternative GGX offers
ALTERNATIVES = [(p, c) for p in MODEL.positions for c in MODEL.choices(p)[K:]]


def state_with(**choices: str) -> str:
    """GGX's state string choosing the named alternatives, e.g. ``state_with(D="beckmann")``."""
    return "".join(str(MODEL.choices(p).index(choices[p])) if p in choices else "0" for p in MODEL.positions)


def random_params(model, n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Every parameter uniform over its range (log-uniform on log scales)."""
    out = {}
    for s in model.specs:
        u = rng.random((n, s.width))
        out[s.name] = s.low * (s.high / s.low) ** u if s.scale == "log" else s.low + (s.high - s.low) * u
    return out


def random_pairs(params, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Half uniform over the hemisphere, half mirrored about half vectors near the shading normal."""
    def hemisphere():
        w = rng.normal(size=(n, 3))
        w /= np.linalg.norm(w, axis=1, keepdims=True)
        w[:, 2] = np.abs(w[:, 2])
        return w
    wi, wo = hemisphere(), hemisphere()
    t, b, nrm = ref.frame(params, n)
    near = slice(n // 2, n)
    ax, ay = params["alpha_x"][near, 0], params["alpha_y"][near, 0]
    h = (-(ax * rng.normal(size=len(ax)))[:, None] * t[near] - (ay * rng.normal(size=len(ay)))[:, None] * b[near]
         + nrm[near])
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    wo[near] = 2.0 * np.sum(wi[near] * h, axis=1, keepdims=True) * h - wi[near]
    return wi, wo


def exact_pairs(wi, wo, params) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """The rows where the model evaluates its formulas as written, with no floor binding: below a
    horizon (both give 0), or every cosine it reads at least ``COS_EPS`` (``neuenh.shading``), and,
    for the conductor's Fresnel, ηκ at least 1e-5 (its ``a`` is floored at 1e-6: past the critical
    angle a ≈ ηκ/sqrt|t0|, and F moves by up to 4e-6 relative where the floor binds). Elsewhere the
    floors are by design; the stability tests below check them. A few rows in ten thousand of a
    random draw."""
    _, g = ref._geometry(wi, wo, params)
    keep = ~g["above"] | (np.minimum.reduce([g["cos_i"], g["cos_o"], g["cos_h"], g["cos_d"]]) >= COS_EPS)  # 0 below
    if "kappa" in params:
        keep &= (params["eta"] * params["kappa"]).min(axis=1) >= 1e-5
    assert keep.mean() > 0.99, keep.mean()
    return wi[keep], wo[keep], {k: v[keep] for k, v in params.items()}


def evaluate(model, wi, wo, params, dtype=torch.float64) -> np.ndarray:
    tensors = {k: torch.as_tensor(v, dtype=dtype) for k, v in params.items()}
    return model.evaluate(torch.as_tensor(wi, dtype=dtype), torch.as_tensor(wo, dtype=dtype), tensors).double().numpy()


def assert_relative(got, want, rtol, floor, what):
    got, want = np.asarray(got), np.asarray(want)
    assert np.isfinite(got).all(), what
    checked = np.abs(want) > floor
    err = np.where(checked, np.abs(got - want) / np.where(checked, np.abs(want), 1.0), 0.0)
    worst = np.unravel_index(np.argmax(err), err.shape)
    assert err[worst] <= rtol, f"{what}: relative error {err[worst]:.3g} at {worst} (got {got[worst]}, want {want[worst]})"


# ============================================================================================
# 1. Against independent derivations
# ============================================================================================
@pytest.mark.parametrize("position, choice", ALTERNATIVES)
def test_each_alternative_matches_its_papers_formula(position, choice):
    model = get_model("ggx", alternatives=True, state=state_with(**{position: choice}))
    rng = np.random.default_rng(zlib.crc32(choice.encode()))  # not hash(): it changes from run to run
    params = random_params(model, 6000, rng)
    wi, wo, params = exact_pairs(*random_pairs(params, 6000, rng), params)
    want = ref.ggx_with(wi, wo, params, **{position.lower(): choice})
    assert (want > 1e-6).sum() > 4000, "too few non-zero values to be a check"
    assert_relative(evaluate(model, wi, wo, params), want, 1e-6, floor=1e-250, what=f"{position}={choice}")


def test_several_alternatives_at_once_and_cook_torrance_offers_ggx():
    model = get_model("ggx", alternatives=True, state=state_with(M="oren_nayar", D="student_t", F="conductor",
                                                                  G="height_correlated"))
    rng = np.random.default_rng(5)
    params = random_params(model, 3000, rng)
    wi, wo, params = exact_pairs(*random_pairs(params, 3000, rng), params)
    want = ref.ggx_with(wi, wo, params, m="oren_nayar", d="student_t", f="conductor", g="height_correlated")
    assert_relative(evaluate(model, wi, wo, params), want, 1e-6, floor=1e-250, what="four alternatives")
    ct = get_model("cook_torrance", alternatives=True)
    assert ct.choices("D")[:3] == ("beckmann", "mlp16-32-16", "ggx") and "beckmann" not in ct.choices("D")[3:]


# ============================================================================================
# 2. Closed forms
# ============================================================================================
def d_term(choice: str, h: np.ndarray, **values) -> np.ndarray:
    """The D of ``choice`` at local-frame half vectors ``h`` (the geometric frame)."""
    model = get_model("ggx", alternatives=True, state=state_with(D=choice) if choice != "ggx" else None)
    params = {s.name: torch.full((len(h), s.width), float(values.get(s.name, s.init)), dtype=torch.float64)
              for s in model.specs}
    expr = model.chosen_terms().get("D") or model.graph.positions[model.graph.index["D"]]
    hh = torch.as_tensor(h)
    return expr.formula(make_shading(hh, hh, params, TORCH)).numpy()[:, 0]


def projected_area(choice: str, ax: float, ay: float, **values) -> float:
    """∫ D(h) cos θh dω by quadrature in slope space: h ∝ (−x, −y, 1) with (x, y) = (ax ρ cos φ,
    ay ρ sin φ), ρ = tan ψ; cos θh dω = cos⁴θh dx dy (Walter et al. 2007 eq. 4 and Heitz 2014)."""
    psi, w_psi = np.polynomial.legendre.leggauss(600)
    psi, w_psi = (psi + 1) * math.pi / 4, w_psi * math.pi / 4
    n_phi = 32 * max(4, math.ceil(max(ax, ay) / min(ax, ay)))
    phi = (np.arange(n_phi) + 0.5) * 2 * math.pi / n_phi
    rho, drho = np.tan(psi), 1.0 / np.cos(psi) ** 2
    r, p = np.meshgrid(rho, phi, indexing="ij")
    x, y = ax * r * np.cos(p), ay * r * np.sin(p)
    h = np.stack([-x, -y, np.ones_like(x)], axis=-1).reshape(-1, 3)
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    integrand = d_term(choice, h, alpha_x=ax, alpha_y=ay, **values) * h[:, 2] ** 4
    weights = (ax * ay * rho * drho * w_psi)[:, None] * np.full(n_phi, 2 * math.pi / n_phi)
    return float(np.sum(integrand * weights.reshape(-1)))


DISTRIBUTION_CASES = [
    ("ggx", {}), ("beckmann", {}),
    ("gtr", {"gtr_gamma": 1.5}), ("gtr", {"gtr_gamma": 2.0}), ("gtr", {"gtr_gamma": 3.9}),
    ("student_t", {"std_gamma": 1.6}), ("student_t", {"std_gamma": 2.0}), ("student_t", {"std_gamma": 30.0}),
    ("hazy_ggx", {"haze_weight": 0.3, "haze_extent": 4.0}), ("hazy_ggx", {"haze_weight": 0.9, "haze_extent": 10.0}),
]


@pytest.mark.parametrize("alphas", [(0.05, 0.05), (0.3, 0.3), (0.1, 0.6), (0.9, 0.9)])
@pytest.mark.parametrize("choice, values", DISTRIBUTION_CASES, ids=[f"{c}-{v}" for c, v in DISTRIBUTION_CASES])
def test_every_distribution_integrates_to_one(choice, values, alphas):
    assert projected_area(choice, *alphas, **values) == pytest.approx(1.0, abs=2e-4)


def test_the_alternatives_become_the_original_at_their_start():
    """GTR and Student-t at γ = 2 are GGX (GTR isotropically), hazy GGX with no haze is GGX, Schlick
    with tint 1 is Schlick, Oren-Nayar with σ = 0 is Lambert; Student-t tends to Beckmann as γ grows;
    a conductor with κ = 0 is a dielectric of index η."""
    rng = np.random.default_rng(3)
    h = rng.normal(size=(4000, 3))
    h[:, 2] = np.abs(h[:, 2]) + 0.05
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    iso = dict(alpha_x=0.3, alpha_y=0.3)
    ggx = d_term("ggx", h, **iso)
    np.testing.assert_allclose(d_term("gtr", h, gtr_gamma=2.0, **iso), ggx, rtol=2e-3)  # a² clamp: 0.09 exact
    np.testing.assert_allclose(d_term("student_t", h, std_gamma=2.0, alpha_x=0.2, alpha_y=0.5),
                               d_term("ggx", h, alpha_x=0.2, alpha_y=0.5), rtol=1e-12)
    np.testing.assert_allclose(d_term("hazy_ggx", h, haze_weight=0.0, **iso), ggx, rtol=1e-12)
    peak = h[:, 2] > 0.95
    np.testing.assert_allclose(d_term("student_t", h, std_gamma=40.0, **iso)[peak],
                               d_term("beckmann", h, **iso)[peak], rtol=0.05)
    cos = np.linspace(0.01, 1.0, 200)
    f0 = np.full(200, 0.2)
    np.testing.assert_allclose(ref.schlick_tint_f(cos, f0, np.ones((200, 3))), ref.schlick(f0, cos)[:, None].repeat(3, 1))
    np.testing.assert_allclose(ref.conductor_f(cos, np.full((200, 3), 1.5), np.zeros((200, 3)))[:, 0],
                               dielectric_fresnel(torch.as_tensor(cos), 1.5).numpy(), rtol=1e-9)
    np.testing.assert_allclose(ref.oren_nayar_factor(cos, 0.3, cos[::-1], 1.0, 0.0), 1.0)
    # and the library at the same points: its terms at their parameters' starts
    model = get_model("ggx", alternatives=True, state=state_with(F="schlick_tint", M="oren_nayar", D="student_t"))
    plain = get_model("ggx")
    params = random_params(plain, 2000, rng)
    wi, wo = random_pairs(params, 2000, rng)
    starts = {s.name: np.full((2000, s.width), s.init) for s in model.specs if s.name not in params}
    np.testing.assert_allclose(evaluate(model, wi, wo, {**params, **starts, "on_sigma": np.zeros((2000, 1))}),
                               evaluate(plain, wi, wo, params), rtol=1e-9, atol=1e-300)


# ============================================================================================
# 3. Stability
# ============================================================================================
def hard_cases(model) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Grazing, below either horizon, into the surface, mirror peaks; roughness 1e-4..1; every extra
    parameter at both ends of its range; a tilted shading frame."""
    def d(theta, phi=0.0):
        t, p = math.radians(theta), math.radians(phi)
        return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])
    z = np.array([0.0, 0.0, 1.0])
    pairs = [(z, z), (d(45, 30), d(45, 210)), (d(89.9), z), (z, d(89.9, 200)), (d(89.9), d(89.9, 90)),
             (d(89.9, 45), d(89.9, 45)), (d(100), z), (d(20), d(135, 60)), (-z, -z), (d(37, 25), -d(37, 25)),
             (np.array([1.0, 0.0, 0.0]), z), (d(89.99, 10), d(89.99, 190))]
    wis, wos, rows = [], [], []
    for alphas in [(1e-4, 1e-4), (1e-3, 1.0), (0.3, 0.3), (1.0, 1.0)]:
        for end in ("low", "high"):
            for frame in [dict(normal=(0.0, 0.0), t_theta=0.0), dict(normal=(0.5, -0.4), t_theta=1.0)]:
                for wi, wo in pairs:
                    wis.append(wi), wos.append(wo)
                    rows.append({"alpha_x": alphas[0], "alpha_y": alphas[1], "end": end, **frame})
    params = {}
    for s in model.specs:
        def value(row):
            if s.name in row:
                return row[s.name]
            return s.low if row["end"] == "low" else s.high
        params[s.name] = np.stack([np.broadcast_to(np.asarray(value(r), dtype=np.float64), (s.width,)) for r in rows])
    return np.stack(wis), np.stack(wos), params


ALL_AT_ONCE = [dict(M="oren_nayar", D=d, F=f, G="height_correlated")
               for d, f in [("beckmann", "conductor"), ("gtr", "schlick_tint"), ("student_t", "conductor"),
                            ("hazy_ggx", "schlick_tint")]]


@pytest.mark.parametrize("choices", ALL_AT_ONCE, ids=[c["D"] + "-" + c["F"] for c in ALL_AT_ONCE])
def test_hard_cases_are_finite_zero_below_and_have_finite_gradients(choices):
    model = get_model("ggx", alternatives=True, state=state_with(**choices))
    wi, wo, params = hard_cases(model)
    got = evaluate(model, wi, wo, params)
    assert np.isfinite(got).all() and (got >= 0).all()
    above = (wi[:, 2] > 0) & (wo[:, 2] > 0) & (np.sum(wi * ref.frame(params, len(wi))[2], 1) > 0) \
        & (np.sum(wo * ref.frame(params, len(wi))[2], 1) > 0)
    assert (got[~above] == 0).all()
    assert_relative(got, ref.ggx_with(wi, wo, params, **{k.lower(): v for k, v in choices.items()}), 1e-5,
                    floor=1e-200, what="hard cases")
    assert evaluate(model, wi, wo, params, dtype=torch.float32).max() > 1e4  # the 1e-4 roughness peaks
    # float32 through the constrained mapping, as training sees it: finite gradients for every
    # parameter read (every alternative's own ones among them) and none for the alternatives not chosen
    n = len(wi)
    table = MaterialTable(model.specs, [f"m{i}" for i in range(n)], model.latent_dim,
                          raw={s.name: s.to_raw(torch.as_tensor(params[s.name])) for s in model.specs})
    values, latent = table.gather(torch.arange(n))
    wi32 = torch.as_tensor(wi, dtype=torch.float32)
    f = model(wi32, torch.as_tensor(wo, dtype=torch.float32), values, latent)
    (torch.log1p(f * wi32[:, 2:3].clamp_min(0)).sum() + 1e-6 * f.sum()).backward()
    used = set(model.used_specs().names)
    own = set(model.module_specs.names)
    for name, raw in table.raw.items():
        if name in used - own or (name in own and raw.grad is not None):
            assert raw.grad is not None and torch.isfinite(raw.grad).all(), name
            assert raw.grad.abs().sum() > 0, f"no gradient reaches {name}"
        elif name not in own:
            assert raw.grad is None, f"{name} is not read by {model.describe()}"


def test_the_conductors_fresnel_is_a_reflectance_with_finite_gradients_at_its_edges():
    """In float32, on every edge of its domain at once — grazing (cosine COS_EPS), normal incidence,
    exactly a dielectric's critical angle (cos² = 1 − η², κ = 0), index-matched (η = 1, κ = 0),
    κ of 0, 1e-30 and the range's 8 —: F in [0, 1] and every gradient finite. The critical angle
    gave NaN gradients (the square root of t0² + 4η²κ² at 0), index-matched grazing F = −1/3."""
    from neuenh.models.alternatives import conductor_fresnel

    etas, kappas = [0.05, 0.5, 0.999, 1.0, 1.5, 4.0], [0.0, 1e-30, 1e-12, 1e-6, 1e-3, 1.0, 8.0]
    cosines = [COS_EPS, 1e-3, 0.1, *(math.sqrt(1.0 - e * e) for e in etas if e < 1.0), 0.999999, 1.0]
    grid = torch.tensor([(c, e, k) for c in cosines for e in etas for k in kappas], dtype=torch.float32)
    cos, eta, kappa = (grid[:, i : i + 1].clone().requires_grad_() for i in range(3))
    f = conductor_fresnel(TORCH, cos, eta, kappa)
    f.sum().backward()
    assert ((f >= 0) & (f <= 1 + 4 * torch.finfo(torch.float32).eps)).all(), grid[((f < 0) | (f > 1)).squeeze(1)]
    for name, x in (("cos", cos), ("eta", eta), ("kappa", kappa)):
        assert torch.isfinite(x.grad).all(), (name, grid[~torch.isfinite(x.grad).squeeze(1)])


def test_the_conductors_fresnel_keeps_float32_accuracy_past_the_critical_angle():
    """Past a weakly absorbing conductor's critical angle (η < 1, κ ≪ η) the textbook
    a² = (sqrt(t0² + 4η²κ²) + t0) / 2 cancels (t0 < 0): in float32 it lost up to 5.9e-4 relative here.
    Written without the cancellation it is a few float32 roundings of the float64 complex
    formula (``reference_brdfs.conductor_f``), at the same float32 inputs."""
    from neuenh.models.alternatives import conductor_fresnel

    rng = np.random.default_rng(1)
    eta = rng.uniform(0.05, 0.9, 4000).astype(np.float32)
    cos = (rng.uniform(0.01, 0.99, 4000) * np.sqrt(1.0 - eta.astype(np.float64) ** 2)).astype(np.float32)
    kappa = (10.0 ** rng.uniform(-5, -1, 4000)).astype(np.float32)
    got = conductor_fresnel(TORCH, *(torch.from_numpy(v)[:, None] for v in (cos, eta, kappa))).double().numpy()[:, 0]
    cos64, eta64, kappa64 = (v.astype(np.float64) for v in (cos, eta, kappa))
    want = ref.conductor_f(cos64, eta64[:, None], kappa64[:, None])[:, 0]
    # ~25 float32 operations, none cancelling: each a rounding of at most eps/2
    assert np.max(np.abs(got - want) / want) <= 25 * np.finfo(np.float32).eps / 2


# ============================================================================================
# 4. The model's contract
# ============================================================================================
def test_choices_are_named_by_digit_and_count_per_position():
    assert MODEL.choices("D") == ("ggx", "mlp16-32-16", "beckmann", "gtr", "student_t", "hazy_ggx")
    assert MODEL.choices("F") == ("schlick", "mlp16-32-16", "conductor", "schlick_tint")
    assert MODEL.choices("S*D") == ("multiply", "mlp16-32-16")
    assert MODEL.digit_counts == (3, 2, 6, 4, 3, 2, 2, 2, 2, 2, 2)
    assert get_model("ggx").digit_counts == (2,) * 11 and get_model("ggx").choice_names() == {}
    model = get_model("ggx", alternatives=True, state=state_with(D="student_t", F="conductor"))
    assert model.describe() == "M + ((((S * D[student_t]) * F[conductor]) * G) * invE)"
    assert not model.has_modules and not model.uses_latent and len(model.neural) == 0
    assert model.used_specs().names == (*get_model("ggx").param_names, "std_gamma", "eta", "kappa")
    assert model.n_material_params() == 12 + 1 + 6
    assert MODEL.choice_names()[("D", 4)] == "student_t"
    with pytest.raises(ValueError, match="digit '2' at position S is not in 0..1"):
        get_model("ggx", alternatives=True, state="02000000000")
    with pytest.raises(ValueError, match="offers no alternative"):
        get_model("ward", alternatives=True)


def test_evaluate_needs_only_the_parameters_the_state_reads():
    model = get_model("ggx", alternatives=True, state=state_with(D="gtr"))
    plain = {s.name: torch.full((s.width,), s.init) for s in get_model("ggx").specs}
    wi = wo = torch.tensor([[0.0, 0.0, 1.0]])
    with pytest.raises(ValueError, match="missing parameter.*gtr_gamma"):
        model.evaluate(wi, wo, plain)
    assert torch.isfinite(model.evaluate(wi, wo, {**plain, "gtr_gamma": torch.tensor([2.5])})).all()
    with pytest.raises(ValueError, match="gtr_gamma.*must lie in"):
        model.evaluate(wi, wo, {**plain, "gtr_gamma": torch.tensor([0.5])})


@pytest.mark.parametrize("choices", ALL_AT_ONCE[:2], ids=["beckmann", "gtr"])
def test_specialize_the_numpy_backend_and_a_module_beside_alternatives_equal_evaluate(choices):
    digits = [int(ch) for ch in state_with(**choices)]
    digits[MODEL.positions.index("invE")] = 1  # a neural module too
    digits[MODEL.positions.index("S*D*F*G")] = 1
    model = get_model("ggx", alternatives=True, state="".join(map(str, digits)), seed=3).double()
    rng = np.random.default_rng(11)
    params = {k: v[0] for k, v in random_params(model, 1, rng).items()}
    tensors = MaterialParams({k: torch.as_tensor(v) for k, v in params.items()}, torch.as_tensor(rng.random(model.latent_dim)))
    wi, wo = random_pairs({k: np.broadcast_to(v, (500, len(v))) for k, v in params.items()}, 500, rng)
    want = model.evaluate(torch.as_tensor(wi), torch.as_tensor(wo), tensors)
    special = model.specialize(tensors)
    torch.testing.assert_close(special(torch.as_tensor(wi), torch.as_tensor(wo)), want, rtol=1e-10, atol=1e-12)
    assert special.flops_per_evaluation > 2 * sum(m.flops for m in special.modules.values()) // 2
    for expr in model.graph.positions:  # every alternative term in numpy equals torch
        term = model.chosen_terms().get(expr.name, expr)
        if isinstance(term, Term) and not model.is_neural(model.digits[model.graph.index[expr.name]]):
            values = {k: np.tile(v, (500, 1)) for k, v in params.items()}
            np.testing.assert_allclose(
                np.asarray(term.formula(make_shading(wi, wo, values, NUMPY))),
                term.formula(make_shading(torch.as_tensor(wi), torch.as_tensor(wo),
                                          {k: torch.as_tensor(v) for k, v in values.items()}, TORCH)).numpy(),
                rtol=1e-10, err_msg=expr.name)


def test_a_bundle_with_alternatives_round_trips(tmp_path):
    state = state_with(D="hazy_ggx", G="height_correlated")
    bundle = Bundle.initial("ggx", ["a", "b"], alternatives=True)
    bundle.model = bundle.model.enhance(state[:5] + "1" + state[6:], seed=2)  # invE neural as well
    with torch.no_grad():
        bundle.materials.raw["haze_weight"][1] = 1.5
    bundle.save(tmp_path / "m")
    meta = (tmp_path / "m" / "model.json").read_text()
    assert '"alternatives": true' in meta and '"hazy_ggx"' in meta and '"params_per_material": 41' in meta
    back = Bundle.load(tmp_path / "m")
    assert back.model.state == bundle.model.state and back.model.has_alternatives
    assert back.model.describe() == "M + ((((S * D[hazy_ggx]) * F) * G[height_correlated]) * invE^)"
    assert float(back.materials.raw["haze_weight"][1]) == 1.5
    assert Bundle.from_bytes(bundle.to_bytes()).model.state == bundle.model.state


def test_a_search_ball_gives_each_position_its_own_choices_and_counts_only_modules():
    constraints = Constraints.from_names(MODEL.positions, digit_counts=MODEL.digit_counts, neural=[1])
    m = max(MODEL.digit_counts)
    ball = hamming_ball((0,) * 11, 1, m, constraints)
    assert len(ball) == 1 + sum(c - 1 for c in MODEL.digit_counts) == 20
    assert all(d < MODEL.digit_counts[i] for state in ball for i, d in enumerate(state))
    # at most one module: alternatives do not count towards max_neural
    one = Constraints.from_names(MODEL.positions, digit_counts=MODEL.digit_counts, neural=[1], max_neural=1)
    center = tuple(int(c) for c in state_with(D="beckmann"))
    center = center[:5] + (1,) + center[6:]
    ball = hamming_ball(center, 1, m, one)
    assert all(sum(d == 1 for d in s) <= 1 for s in ball)
    assert any(s[2] == 3 for s in ball) and not any(s[4] == 1 for s in ball)
