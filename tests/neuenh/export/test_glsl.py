"""The GLSL export, run for real: every model's exported material, compiled by glslangValidator
and executed on Mesa's llvmpipe, against the torch model on the hard cases and random directions."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import reference_brdfs as ref
import torch

from gl_runtime import gl_context, run_brdf, shade_sphere, validate
from neuenh.export import identifier
from neuenh.export.glsl import literal, material_source, write
from neuenh.checkpoint import Bundle
from neuenh.materials import MaterialParams
from neuenh.models import available_models, get_model
from neuenh.pretrained import bundle_path
from test_models import DIRECTIONS, FRAMES, random_directions, random_params, spec_values, torch_params

from ggx_states import ALTERNATIVES_STATE, PAPER_STATE

N_RANDOM = 8192  # random pairs per material, besides every hard case in every frame


@pytest.fixture(scope="module")
def gl():
    ctx = gl_context()
    yield ctx
    ctx.release()


def materials(model, rng) -> list[dict[str, np.ndarray]]:
    """The extremes of the stability grid (roughness 1e-4 and 1, a tilted and rotated frame) and two
    random materials, each as one row of parameters."""
    lobe = ([dict(alpha_x=1e-4, alpha_y=1e-4), dict(alpha_x=0.3, alpha_y=0.05), dict(alpha_x=1.0, alpha_y=1.0)]
            if "alpha_x" in model.param_names else [dict(shininess=1e4), dict(shininess=30.0), dict(shininess=1.0)])
    fixed = [spec_values(model, 1, **{k: v for k, v in {**frame, **rough}.items() if k in model.param_names},
                         rho_d=(0.25, 0.5, 0.0), rho_s=(1.0, 0.5, 0.25))
             for frame, rough in zip(FRAMES, lobe)]
    return fixed + [{k: v[i : i + 1] for k, v in random_params(model, 2, rng).items()} for i in range(2)]


def directions(model, params, rng) -> tuple[np.ndarray, np.ndarray]:
    """Every hard case of the stability grid (grazing, below either horizon, mirror, into the
    surface) about this material's normal, then random pairs, half of them near its peak."""
    normal = ref.frame(params, 1)[2][0]
    hard = [make(normal) for make in DIRECTIONS.values()]
    wi, wo = random_directions({k: np.repeat(v, N_RANDOM, 0) for k, v in params.items()}, N_RANDOM, rng)
    unit = lambda w: w / np.linalg.norm(w, axis=-1, keepdims=True)  # noqa: E731
    return (np.vstack([unit(np.array([h[0] for h in hard])), wi]),
            np.vstack([unit(np.array([h[1] for h in hard])), wo]))


# Every model's analytical terms; the module code on the paper's state (a term module reading
# directions, operator modules) and on every position of Ward neural (modules over constants and
# RGB operands too). Each neural shader takes llvmpipe seconds to compile, so not every model's.
# And GGX with alternative terms beside a module (ALTERNATIVES_STATE: an RGB Fresnel, Oren-Nayar).
CASES = [(m, "0" * len(get_model(m).positions)) for m in available_models()] + [
    ("ggx", PAPER_STATE), ("ward", "1111111"), ("ggx-alternatives", ALTERNATIVES_STATE)]


def model_for(name: str, state: str):
    if name == "ggx-alternatives":
        return get_model("ggx", alternatives=True, state=state)
    return get_model(name, state=state)


def check_export(gl, model, material: MaterialParams, wi: np.ndarray, wo: np.ndarray, what: str) -> None:
    """The exported material on llvmpipe against the float64 model at the same float32 directions."""
    special = model.specialize(material)
    wi, wo = wi.astype(np.float32), wo.astype(np.float32)  # what the shader reads
    got = run_brdf(gl, material_source(special, "m"), wi, wo).astype(np.float64)
    wi64, wo64 = torch.as_tensor(wi, dtype=torch.float64), torch.as_tensor(wo, dtype=torch.float64)
    with torch.no_grad():
        want = copy.deepcopy(model).double().evaluate(wi64, wo64, material.to(torch.float64)).numpy()
    want32 = special(wi64.float(), wo64.float()).double().numpy()  # torch's own float32 path
    assert np.isfinite(got).all(), what
    assert (got[(want == 0).all(1)] == 0).all(), f"{what}: non-zero below a horizon"
    scale = np.maximum(np.abs(want), 1e-3 * want.max())  # relative where f_r >= 1e-3 of its max
    error, own = np.abs(got - want) / scale, np.abs(want32 - want) / scale
    # float32 itself is off by more than 1e-4 at the sharpest lobes (an ulp of direction moves a
    # roughness-1e-4 peak; exp(1e4 log cos) amplifies log's rounding): there the export must be
    # about as good as torch's own float32 path
    bound = max(1e-4, 2.5 * float(own.max()))
    assert error.max() <= bound, f"{what}: max relative error {error.max():.3g} > {bound:.3g}"


@pytest.mark.parametrize("name, state", CASES)
def test_exported_glsl_equals_the_torch_model_on_llvmpipe(gl, name, state, tmp_path):
    rng = np.random.default_rng(7)
    torch.manual_seed(0)
    model = model_for(name, state)
    checked, chosen = 0, materials(model, rng)
    if "1" in state:  # a neural shader takes llvmpipe a second or more to compile: the extremes and one random
        chosen = [chosen[0], chosen[2], chosen[3]]
    for i, params in enumerate(chosen):
        latent = torch.as_tensor(rng.random(model.latent_dim)) if model.uses_latent else None
        material = MaterialParams(torch_params({k: v[0] for k, v in params.items()}, torch.float64), latent)
        if i == 0:
            validate(material_source(model.specialize(material), "m"), tmp_path)
        wi, wo = directions(model, params, rng)
        check_export(gl, model, material, wi, wo, f"{name} {state} material {i}")
        checked += len(wi)
    assert checked >= 3 * N_RANDOM


def test_the_shipped_model_exports_each_of_its_materials(gl, tmp_path):
    path = bundle_path("enhanced-ggx")
    if path is None:
        pytest.skip("no shipped models/enhanced-ggx in this tree")
    bundle = Bundle.load(path)
    rng = np.random.default_rng(3)
    for index in (0, len(bundle.materials) - 1):
        material = bundle.materials.as_params(index)
        params = {k: v.double().numpy()[None] for k, v in material.values.items()}
        wi, wo = directions(bundle.model, params, rng)
        check_export(gl, bundle.model, material, wi, wo, f"enhanced-ggx {bundle.materials.names[index]}")
    validate(material_source(bundle.model.specialize(bundle.materials.as_params(0)), "m"), tmp_path)


def test_write_names_files_and_refuses_clashes(tmp_path):
    model = get_model("ggx")
    one = {k: v for k, v in torch_params({s.name: np.full(s.width, s.init) for s in model.specs}).items()}
    paths = write(model, {"brushed steel": one, "9-gold": one}, tmp_path)
    assert [p.name for p in paths] == ["brushed_steel.glsl", "m9_gold.glsl", "ggx-generic.glsl"]
    text = paths[0].read_text()
    assert "vec3 neuenh_brushed_steel_brdf(vec3 wi, vec3 wo)" in text and "#ifndef NEUENH_NO_DEFAULT_BRDF" in text
    assert not any(line.startswith("#version") for line in text.splitlines()) and "void main" not in text
    with pytest.raises(ValueError, match="'a b' and 'a-b' both export as a_b.glsl"):
        write(model, {"a b": one, "a-b": one}, tmp_path)


def test_two_materials_in_one_shader_by_their_own_names(gl, tmp_path):
    model = get_model("ggx")
    base = {s.name: np.full(s.width, s.init) for s in model.specs}
    rough, mirror_like = ({**base, "alpha_x": np.array([a]), "alpha_y": np.array([a])} for a in (0.5, 0.05))
    sources = [material_source(model.specialize(torch_params(p)), n) for p, n in ((rough, "rough"), (mirror_like, "shiny"))]
    both = "#define NEUENH_NO_DEFAULT_BRDF\n" + "".join(sources)
    wi = wo = np.tile([[0.0, 0.0, 1.0]], (64, 1))
    rough_out = run_brdf(gl, both, wi, wo, call="neuenh_rough_brdf")
    shiny_out = run_brdf(gl, both, wi, wo, call="neuenh_shiny_brdf")
    assert shiny_out[0, 1] > 10 * rough_out[0, 1]  # at normal incidence the sharper lobe peaks higher


@pytest.mark.parametrize("value, text", [(1.0, "1.0"), (-2.5, "(-2.5)"), (1e-06, "1e-06"), (3, "3.0"),
                                         (float("inf"), "uintBitsToFloat(0x7F800000u)")])
def test_literals(value, text):
    assert literal(value) == text


@pytest.mark.parametrize("material, name", [("chm orange", "chm_orange"), ("__x__", "x"), ("3d", "m3d"), ("", "material")])
def test_identifiers(material, name):
    assert identifier(material) == name


@pytest.mark.parametrize("state", ["00000000000", PAPER_STATE])
def test_a_sphere_shaded_by_the_export_equals_the_renderer(gl, state):
    from neuenh.render.lights import DirectionalLight
    from neuenh.render.render import render
    from neuenh.render.scene import sphere_scene

    model = get_model("ggx", state=state)
    base = {s.name: np.full(s.width, s.init) for s in model.specs}
    params = torch_params({**base, "alpha_x": np.array([0.15]), "alpha_y": np.array([0.4]), "t_theta": np.array([0.6]),
                           "rho_d": np.array([0.3, 0.1, 0.05]), "rho_s": np.array([0.9, 0.8, 0.6])}, torch.float32)
    params = MaterialParams(params, torch.full((model.latent_dim,), 0.3) if model.uses_latent else None)
    special = model.specialize(params)
    lights = [((0.3, 0.8, 1.0), (3.0, 3.0, 3.0)), ((-1.0, 0.2, 0.4), (0.5, 0.7, 1.0)), ((0.0, -0.5, 1.0), (1.0, 0.4, 0.2))]
    scene = sphere_scene(48)
    want = render(special, scene, [DirectionalLight(d, e) for d, e in lights])[scene.mask].numpy()
    got = shade_sphere(gl, material_source(special, "ball"), scene.frames().numpy(),
                       scene.wo_local[scene.mask].numpy(), lights)
    assert want.max() > 0.1 and np.isfinite(got).all()
    error = np.abs(got - want) / np.maximum(np.abs(want), 1e-3 * want.max())
    assert error.max() <= 1e-3, f"max relative error {error.max():.3g} over {len(want)} pixels"


GENERIC_CASES = [("ggx", "00000000000"), ("ggx", PAPER_STATE), ("ggx-alternatives", ALTERNATIVES_STATE),
                 ("cook_torrance", "00000000000")]


@pytest.mark.parametrize("name, state", GENERIC_CASES)
def test_the_generic_model_function_equals_the_model_for_any_material(gl, name, state, tmp_path):
    """``neuenh_MODEL_brdf(wi, wo, p)``, the model for any material: compiled by glslangValidator, run
    on llvmpipe with several materials' parameters packed into ``p`` (``pack_parameters``), against
    the float64 model on the hard cases and random pairs."""
    from neuenh.export.glsl import model_source, pack_parameters, parameter_layout

    torch.manual_seed(0)
    model = model_for(name, state)
    source = model_source(model)
    rng = np.random.default_rng(3)
    ident = model.name
    n = sum(width for _, _, width in parameter_layout(model))
    for i, params in enumerate(materials(model, rng)[1:4]):
        latent = torch.as_tensor(rng.random(model.latent_dim)) if model.uses_latent else None
        material = MaterialParams(torch_params({k: v[0] for k, v in params.items()}, torch.float64), latent)
        packed = ", ".join(literal(v) for v in pack_parameters(model, material))
        wrapper = source + (f"vec3 call(vec3 wi, vec3 wo) {{ float p[{n}] = float[{n}]({packed}); "
                            f"return neuenh_{ident}_brdf(wi, wo, p); }}\n")
        if i == 0:
            validate(wrapper, tmp_path, call="call")
        wi, wo = directions(model, params, rng)
        wi32, wo32 = wi.astype(np.float32), wo.astype(np.float32)
        got = run_brdf(gl, wrapper, wi32, wo32, call="call").astype(np.float64)
        with torch.no_grad():
            want = copy.deepcopy(model).double().evaluate(torch.as_tensor(wi32, dtype=torch.float64),
                                                          torch.as_tensor(wo32, dtype=torch.float64), material).numpy()
            own = model.float().evaluate(torch.as_tensor(wi32), torch.as_tensor(wo32),
                                         material.to(torch.float32)).double().numpy()
        assert np.isfinite(got).all() and (got[(want == 0).all(1)] == 0).all()
        scale = np.maximum(np.abs(want), 1e-3 * want.max())
        bound = max(1e-4, 2.5 * float((np.abs(own - want) / scale).max()))  # as float32 torch can do
        assert (np.abs(got - want) / scale).max() <= bound, f"{name} {state} material {i}"
    assert "uniform Neuenh" in source and "material_brdf" in source
