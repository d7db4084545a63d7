"""The Mitsuba 3 export (``neuenh.export.mitsuba``), run in Mitsuba itself (``llvm_ad_rgb``):

1. the plugin's ``eval`` equals the specialized evaluator times the light's cosine (Mitsuba's
   convention): the contract test over every format, ``test_equals_specialized``;
2. its sampling passes Mitsuba's own chi-square test (``mitsuba.chi2``) for rough, anisotropic and
   tilted materials and several incident directions;
3. the exported *plain* GGX (f0 = 1, ρs = 1, ρd = 0) equals Mitsuba's built-in ``roughconductor``
   (GGX, a perfect mirror's Fresnel) with matched roughness — in ``eval`` exactly, and in a rendered
   image within Monte-Carlo noise — which pins the frame, the anisotropy's axes and the cosine;
4. the written scene loads and renders.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

mi_module = pytest.importorskip("mitsuba", reason="the mitsuba package (neuenh[export]) is not installed")

from neuenh.export import mitsuba as nm  # noqa: E402
from neuenh.models import get_model  # noqa: E402
from neuenh.materials import MaterialParams  # noqa: E402
from test_equals_specialized import hard_and_random  # noqa: E402
from test_models import random_params  # noqa: E402

from ggx_states import PAPER_STATE  # noqa: E402

if nm.find_libllvm() is None:
    pytest.skip(f"Mitsuba's LLVM variant needs libLLVM {nm.LLVM_MIN}+ (Debian: apt-get install libllvm19; "
                "make mitsuba)", allow_module_level=True)
mi = nm.set_variant("llvm_ad_rgb")
nm.register()
import drjit as dr  # noqa: E402


def material(model, rng, **fixed) -> MaterialParams:
    params = {k: torch.as_tensor(v[0]) for k, v in random_params(model, 1, rng).items()}
    params.update({k: torch.as_tensor(np.atleast_1d(v), dtype=torch.float64) for k, v in fixed.items()})
    return MaterialParams(params, torch.as_tensor(rng.random(model.latent_dim)) if model.uses_latent else None)


def exported(model, params, tmp_path, name="m"):
    nm.write(model, {name: params}, tmp_path)
    return mi.load_dict({"type": "neuenh", "filename": str(tmp_path / f"{name}.json")})


def eval_mitsuba(bsdf, light: np.ndarray, view: np.ndarray) -> np.ndarray:
    si = dr.zeros(mi.SurfaceInteraction3f, len(light))
    si.wi = mi.Vector3f(view.T.astype(np.float32))
    return np.array(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(light.T.astype(np.float32)))).T.astype(np.float64)


def test_inactive_lanes_are_zero_and_leave_the_others_alone(tmp_path):
    """The plugin skips the model where Mitsuba's ``active`` mask is false (``DrJitMaterial``'s
    conditional): those lanes are zero, every other lane is the unmasked value, bit for bit."""
    rng = np.random.default_rng(5)
    model = get_model("ggx")
    params = material(model, rng, alpha_x=0.3, alpha_y=0.3)
    bsdf = exported(model, params, tmp_path)
    light, view = hard_and_random({k: v.numpy().reshape(1, -1) for k, v in params.values.items()}, rng, n=512)
    si = dr.zeros(mi.SurfaceInteraction3f, len(light))
    si.wi = mi.Vector3f(view.T.astype(np.float32))
    wo = mi.Vector3f(light.T.astype(np.float32))
    active = rng.random(len(light)) < 0.5
    full = np.array(bsdf.eval(mi.BSDFContext(), si, wo)).T
    masked = np.array(bsdf.eval(mi.BSDFContext(), si, wo, mi.Bool(active))).T
    assert (full[active] > 0).any()
    np.testing.assert_array_equal(masked[active], full[active])
    assert (masked[~active] == 0).all()


@pytest.mark.parametrize("fixed, wi", [
    (dict(alpha_x=0.3, alpha_y=0.3), [0.0, 0.0, 1.0]),
    (dict(alpha_x=0.4, alpha_y=0.05, t_theta=0.5), [0.6, 0.0, 0.8]),
    (dict(alpha_x=0.15, alpha_y=0.15, normal=[0.4, 0.2]), [-0.3, 0.5, 0.81240384]),
])
def test_sampling_passes_mitsubas_chi_square_test(fixed, wi, tmp_path, monkeypatch):
    from mitsuba.chi2 import BSDFAdapter, ChiSquareTest, SphericalDomain

    monkeypatch.chdir(tmp_path)  # a rejected test writes chi2_data.py (its histograms) into the working folder
    model = get_model("ggx")
    params = material(model, np.random.default_rng(9), **fixed)
    nm.write(model, {"m": params}, tmp_path)
    sample, pdf = BSDFAdapter("neuenh", {"type": "neuenh", "filename": str(tmp_path / "m.json")}, wi=wi)
    test = ChiSquareTest(domain=SphericalDomain(), sample_func=sample, pdf_func=pdf, sample_dim=3,
                         sample_count=400_000)
    assert test.run(), test.messages


@pytest.mark.parametrize("wi", [[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]])
def test_an_nbrdf_networks_sampling_passes_mitsubas_chi_square_test(wi, tmp_path, monkeypatch):
    """A scene plan's per-material network (``neuenh.export.nbrdf``): the same plugin, its lobe read
    off the network."""
    from mitsuba.chi2 import BSDFAdapter, ChiSquareTest, SphericalDomain
    from test_nbrdf_export import random_network

    monkeypatch.chdir(tmp_path)
    nm.write_nbrdf({"m": random_network()}, tmp_path)
    sample, pdf = BSDFAdapter("neuenh", {"type": "neuenh", "filename": str(tmp_path / "m.json")}, wi=wi)
    test = ChiSquareTest(domain=SphericalDomain(), sample_func=sample, pdf_func=pdf, sample_dim=3,
                         sample_count=400_000)
    assert test.run(), test.messages


def test_an_nbrdf_networks_scene_loads_and_renders(tmp_path):
    from test_nbrdf_export import random_network

    paths = nm.write_nbrdf({"felt 2": random_network()}, tmp_path)
    assert {p.name for p in paths} == {"studio.exr", "felt_2.json", "felt_2.xml"}
    image = np.array(mi.render(mi.load_file(str(tmp_path / "felt_2.xml"), spp=4)))
    assert image.shape == (256, 256, 3) and np.isfinite(image).all() and image.mean() > 0.01
    with pytest.raises(ValueError, match="an NBRDF network's material"):
        nm.load_material(tmp_path / "felt_2.json")


ALPHAS = (0.25, 0.1)  # anisotropic: pins which axis is which


def plain_ggx_material() -> dict[str, torch.Tensor]:
    model = get_model("ggx")
    params = {s.name: torch.full((s.width,), s.init, dtype=torch.float64) for s in model.specs}
    params.update(rho_d=torch.zeros(3, dtype=torch.float64), rho_s=torch.ones(3, dtype=torch.float64),
                  f0=torch.ones(1, dtype=torch.float64), alpha_x=torch.tensor([ALPHAS[0]], dtype=torch.float64),
                  alpha_y=torch.tensor([ALPHAS[1]], dtype=torch.float64), normal=torch.zeros(2, dtype=torch.float64),
                  t_theta=torch.zeros(1, dtype=torch.float64))
    return params


BUILTIN = {"type": "roughconductor", "material": "none", "distribution": "ggx", "alpha_u": ALPHAS[0],
           "alpha_v": ALPHAS[1]}


def test_plain_ggx_evaluates_as_mitsubas_own_roughconductor(tmp_path):
    ours = exported(get_model("ggx"), plain_ggx_material(), tmp_path)
    builtin = mi.load_dict(BUILTIN)
    rng = np.random.default_rng(1)
    light, view = (w / np.linalg.norm(w, axis=1, keepdims=True) for w in rng.normal(size=(2, 20000, 3)))
    light[:, 2], view[:, 2] = np.abs(light[:, 2]), np.abs(view[:, 2])
    a, b = eval_mitsuba(ours, light, view), eval_mitsuba(builtin, light, view)
    assert (b > 0).mean() > 0.9
    np.testing.assert_allclose(a, b, rtol=2e-4, atol=1e-6)


def render(bsdf: dict, spp: int) -> np.ndarray:
    scene = mi.load_dict({
        "type": "scene", "integrator": {"type": "direct"},
        "sensor": {"type": "perspective", "fov": 35,
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 4], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 40, "height": 40, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": spp}},
        "light": {"type": "directional", "direction": [-0.4, -0.5, -1.0], "irradiance": {"type": "rgb", "value": 3.0}},
        "sky": {"type": "constant", "radiance": {"type": "rgb", "value": 0.2}},
        "ball": {"type": "sphere", "bsdf": bsdf}})
    return np.array(mi.render(scene, seed=7))


def test_plain_ggx_renders_the_image_of_mitsubas_roughconductor(tmp_path):
    nm.write(get_model("ggx"), {"m": plain_ggx_material()}, tmp_path)
    ours = render({"type": "neuenh", "filename": str(tmp_path / "m.json")}, 256)
    theirs = render(BUILTIN, 256)
    covered = theirs.sum(-1) > 0
    assert covered.mean() > 0.2 and np.isfinite(ours).all()
    # the same radiance within Monte-Carlo noise: the whole image to 2 %, the pixels' median to 10 %
    assert ours.sum() == pytest.approx(theirs.sum(), rel=0.02)
    rel = np.abs(ours - theirs)[covered] / np.maximum(theirs[covered], 1e-3)
    assert np.median(rel) < 0.10


def test_the_written_scene_loads_and_renders(tmp_path):
    model = get_model("ggx", state=PAPER_STATE, seed=1)
    params = material(model, np.random.default_rng(2), alpha_x=0.2, alpha_y=0.2)
    paths = nm.write(model, {"brushed steel": params}, tmp_path)
    assert {p.name for p in paths} == {"neuenh-model", "studio.exr", "brushed_steel.json", "brushed_steel.xml"}
    scene = mi.load_file(str(tmp_path / "brushed_steel.xml"), spp=4)
    image = np.array(mi.render(scene))
    assert image.shape == (256, 256, 3) and np.isfinite(image).all() and image.mean() > 0.01


def test_a_bad_material_file_is_a_clear_error(tmp_path):
    (tmp_path / "x.json").write_text('{"format": "something else"}')
    with pytest.raises(Exception, match="not a neuenh Mitsuba material"):
        mi.load_dict({"type": "neuenh", "filename": str(tmp_path / "x.json")})
