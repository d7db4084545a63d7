"""The GLSL export, run for real: compiled by glslangValidator and executed on Mesa's llvmpipe.

Every material equals the specialized evaluator in the contract test over every format
(``test_equals_specialized``); here, what is GLSL's own: every case's source compiles with Khronos'
reference compiler, file names and literals, two materials in one shader by their names, a sphere
shaded by the export equals the renderer, and the generic model function equals the model.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch

from gl_runtime import gl_context, run_brdf, shade_sphere, validate
from neuenh.export import identifier
from neuenh.export.glsl import literal, material_source, write
from neuenh.materials import MaterialParams
from neuenh.models import get_model
from float32_bounds import assert_within, moved_shading, relative_bound
from test_equals_specialized import ADAPTERS, CASES, GLSL_450, Tier, case_materials
from test_models import torch_params

from ggx_states import ALTERNATIVES_STATE, PAPER_STATE


GLSL = next(adapter for adapter in ADAPTERS if adapter.name == "glsl")


@pytest.fixture(scope="module")
def gl():
    ctx = gl_context()
    yield ctx
    ctx.release()


@pytest.mark.parametrize("case", [case for case in CASES if case not in GLSL.skips])
def test_every_case_compiles_with_glslang(case, tmp_path):
    """A random material of each case the GLSL adapter runs (and the shipped model's own) in the
    compute harness."""
    model, shipped = CASES[case]()
    materials = case_materials(model, shipped, np.random.default_rng(7))
    for m in [m for m in materials if m.tier == Tier.FIRST]:
        validate(material_source(model.specialize(m.params), "m"), tmp_path)


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


def model_for(name: str, state: str):
    if name == "ggx-alternatives":
        return get_model("ggx", alternatives=True, state=state)
    return get_model(name, state=state)


@pytest.mark.parametrize("name, state", GENERIC_CASES)
def test_the_generic_model_function_equals_the_model_for_any_material(gl, name, state, tmp_path):
    """``neuenh_MODEL_brdf(wi, wo, p)``, the model for any material: compiled by glslangValidator, run
    on llvmpipe with several materials' parameters packed into ``p`` (``pack_parameters``): finite,
    exactly 0 below either horizon, and within ``float32_bounds``' bound of the float64 model with
    GLSL's documented function accuracy (``GLSL_450``), on two grid extremes and a random material."""
    from neuenh.export.glsl import model_source, pack_parameters, parameter_layout

    torch.manual_seed(0)
    model = model_for(name, state)
    model64 = copy.deepcopy(model).double()
    source = model_source(model)
    n = sum(width for _, _, width in parameter_layout(model))
    chosen = [m for m in case_materials(model, [], np.random.default_rng(3)) if m.tier <= Tier.EXTREMES][1:4]
    for i, m in enumerate(chosen):
        packed = ", ".join(literal(v) for v in pack_parameters(model, m.params))
        wrapper = source + (f"vec3 call(vec3 wi, vec3 wo) {{ float p[{n}] = float[{n}]({packed}); "
                            f"return neuenh_{model.name}_brdf(wi, wo, p); }}\n")
        if i == 0:
            validate(wrapper, tmp_path, call="call")
        got = run_brdf(gl, wrapper, m.wi, m.wo, call="call")
        what = f"{name} {state} material {i}"
        assert np.isfinite(got).all() and (got >= 0).all() and (got[~m.above] == 0).all(), what
        wi, wo, material32 = torch.as_tensor(m.wi), torch.as_tensor(m.wo), m.params.to(torch.float32)
        with torch.no_grad():
            truth, bound = relative_bound(lambda a, b, p=m.params: model64.evaluate(a, b, p).numpy(),
                                          lambda a, b, p=material32: model.float().evaluate(a, b, p).double().numpy(),
                                          wi, wo, model.specialize(m.params).flops_per_evaluation + 2 * model.n_weights(),
                                          moved_intermediates=moved_shading, functions=GLSL_450)
        assert_within(got, truth, bound, what)
    assert "uniform Neuenh" in source and "material_brdf" in source
