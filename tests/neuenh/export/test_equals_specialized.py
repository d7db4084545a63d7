"""Every export format's artifact equals the ``SpecializedBRDF`` it was exported from.

One table of adapters, one per format (as Mitsuba 3's chi-square test lists its BSDFs in one adapter
table, ``mitsuba.chi2``), and one contract test over (format x case). An adapter writes a case's
materials into a temporary folder (through ``neuenh.export.export``: the files a user gets; ONNX
without the generic graph), runs each file in the format's own runtime at float32 directions and
returns f_r (n, 3); a format whose runtime is missing skips, naming what to install.

The contract, on every row of every material of every case:

* finite and >= 0;
* exactly 0 below either horizon (the geometric one or the material's shading frame's);
* within ``float32_bounds``' arithmetic bound of the specialized evaluator in float64 at the float32
  directions the artifact reads: u (C (kappa + kappa_s) + n) + C e32 (+ e_fn), with n the specialized
  evaluator's operation count (plus the adapter's own), kappa its measured condition in the
  directions, kappa_s in the shading quantities (an artifact computes the half vector and the cosines
  in its own order: ``moved_shading``), e32 torch's float32 path's own error at and around the row,
  and e_fn, for a runtime whose exp, log, sqrt are documented as less accurate (GLSL), the change of
  float64 f_r with its functions moved by that documented worst case.

Cases (``CASES``): every analytical model; GGX in the paper's enhanced state, with every position
neural (operator modules, a constant module), and with alternative terms beside a module; Ward with
every position neural (modules over constants and RGB operands); the shipped enhanced GGX with three
of its own materials. Materials of a case (``case_materials``): every material of the stability grid
(frames, roughness 1e-4..1, f0 0 and 1) on its 16 hard direction pairs (grazing, mirror, below
either horizon, into the surface), then two random materials and the shipped ones on the hard pairs
about their normal and ``N_RANDOM`` random pairs, half of them near the peak. An adapter whose
runtime compiles each material slowly runs fewer of them (``Tier``).
"""

from __future__ import annotations

import dataclasses
import enum
from pathlib import Path
from typing import Callable

import numpy as np
import pytest
import reference_brdfs as ref
import torch

from neuenh.export import export
from neuenh.materials import MaterialParams
from neuenh.models import available_models, get_model
from neuenh.pretrained import load_model
from float32_bounds import (CONDITION_FACTOR, FunctionAccuracy, Measured, assert_within, function_error, measure,
                            moved_shading)
from test_models import (DIRECTIONS, ROUGHNESS, above_mask, random_directions, random_params, stability_grid,
                         torch_params)

from ggx_states import ALTERNATIVES_STATE, PAPER_STATE

N_RANDOM = 8192  # random pairs per random material, besides the hard pairs about its normal


# -- the adapters ---------------------------------------------------------------------------------
class Tier(enum.IntEnum):
    """How widely a material of a case is run: an adapter runs its case's materials up to a tier
    (``Adapter.tiers``), as its runtime's cost per material allows."""

    FIRST = 0  # the first random material and the first shipped one: every adapter runs them
    EXTREMES = 1  # the grid's extremes (``EXTREMES``), the other random and shipped materials
    GRID = 2  # every other material of the stability grid


@dataclasses.dataclass
class Adapter:
    """One export format in its runtime.

    ``start()`` -> the runtime (a skip naming what to install when it is missing); ``write(model,
    materials, out_dir)`` writes the materials' files (``neuenh.export.export`` unless said); ``run(runtime,
    paths, directions)`` -> f_r (n, 3) float32 of each written material file at its float32 (wi, wo)
    (n, 3), neuenh's convention (``wi`` the light, no cosine factor); ``suffix``: a material's file;
    ``factor``: C of ``float32_bounds``; ``functions``: the runtime's documented accuracy of exp, log
    and sqrt where it is worse than a few ulps (``float32_bounds.FunctionAccuracy``); ``extra_ops``:
    operations the adapter adds after the artifact (they round too); ``tiers``: which of a case's
    materials it runs: the highest ``Tier`` for a model without modules and for one with (its
    runtime's cost per material); ``skips``: cases it cannot run, and why."""

    name: str
    suffix: str
    start: Callable[[], object]
    run: Callable[[object, list[Path], list[tuple[np.ndarray, np.ndarray]]], list[np.ndarray]]
    factor: float = CONDITION_FACTOR
    functions: FunctionAccuracy | None = None
    extra_ops: int = 0
    write: Callable[[object, dict, Path], object] | None = None
    tiers: tuple[Tier, Tier] = (Tier.GRID, Tier.GRID)
    skips: dict[str, str] = dataclasses.field(default_factory=dict)  # case -> why this runtime cannot run it


def _onnx_start():
    return pytest.importorskip("onnxruntime", reason="onnxruntime (neuenh[export]) is not installed")


def _onnx_write(model, materials, out_dir: Path) -> None:
    """Each material's graph, as ``neuenh.export.onnx.write`` writes it, without the generic graph
    that ``write`` adds (a second of graph building a case; test_onnx runs it)."""
    from neuenh.export.onnx import material_graph

    for name, params in materials.items():
        (out_dir / f"{name}.onnx").write_bytes(material_graph(model.specialize(params), name=name))


def _onnx_run(ort, paths, directions):
    options = ort.SessionOptions()
    options.log_severity_level = 3
    out = []
    for path, (wi, wo) in zip(paths, directions):
        session = ort.InferenceSession(path.read_bytes(), options, providers=["CPUExecutionProvider"])
        out.append(session.run(["f_r"], {"wi": wi, "wo": wo})[0])
    return out


def _glsl_start():
    from gl_runtime import gl_context

    return gl_context()


SHADER_BYTES = 64_000  # llvmpipe's compile time grows faster than the source: materials batched up to this


def _glsl_run(ctx, paths, directions):
    """Materials batched into compute shaders of up to ``SHADER_BYTES`` of source (a larger one, a
    material with modules, alone): row i of a batch calls the function of the material it belongs to."""
    from gl_runtime import run_brdf

    sources = [path.read_text() for path in paths]
    batches: list[list[int]] = []
    for i, source in enumerate(sources):
        if batches and sum(len(sources[j]) for j in batches[-1]) + len(source) <= SHADER_BYTES:
            batches[-1].append(i)
        else:
            batches.append([i])
    out = []
    for batch in batches:
        ends = np.cumsum([len(directions[i][0]) for i in batch])
        calls = "".join(f"    if (i < {end}u) return neuenh_{paths[j].stem}_brdf(wi, wo);\n" for j, end in zip(batch, ends))
        source = ("#define NEUENH_NO_DEFAULT_BRDF\n" + "".join(sources[j] for j in batch)
                  + f"vec3 each_material(vec3 wi, vec3 wo) {{\n    uint i = gl_GlobalInvocationID.x;\n{calls}"
                  "    return vec3(0.0);\n}\n")
        got = run_brdf(ctx, source, np.vstack([directions[j][0] for j in batch]),
                       np.vstack([directions[j][1] for j in batch]), call="each_material")
        out += np.split(got, ends[:-1])
    return out


def _mitsuba_start():
    pytest.importorskip("mitsuba", reason="the mitsuba package (neuenh[export]) is not installed")
    from neuenh.export import mitsuba as nm

    if nm.find_libllvm() is None:
        pytest.skip(f"Mitsuba's LLVM variant needs libLLVM {nm.LLVM_MIN}+ (Debian: apt-get install libllvm19; "
                    "make mitsuba)")
    mi = nm.set_variant("llvm_ad_rgb")
    nm.register()
    return mi


def _mitsuba_run(mi, paths, directions):
    """The plugin's ``eval`` (f_r times the light's cosine, Mitsuba's convention) divided by that
    cosine where it is positive (two more roundings); where it is not, ``eval`` itself, which the
    contract wants 0."""
    import drjit as dr

    out = []
    for path, (wi, wo) in zip(paths, directions):
        bsdf = mi.load_dict({"type": "neuenh", "filename": str(path)})
        si = dr.zeros(mi.SurfaceInteraction3f, len(wi))
        si.wi = mi.Vector3f(wo.T)  # Mitsuba's wi is the viewer, neuenh's wo
        value = np.array(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(wi.T))).T.astype(np.float32)
        cos = wi[:, 2:3]
        out.append(np.where(cos > 0, value / np.where(cos > 0, cos, 1), value).astype(np.float32))
    return out


#: GLSL 4.50 core, Sec. 4.7.1 "Range and Precision" (the figures of GLSL ES 3.00, Sec. 4.5.1, highp):
#: exp within (3 + 2|x|) ULP; log within 3 ULP outside [0.5, 2] and an absolute 2^-21 inside it (so
#: exp(e log cos_h) of a Blinn-Phong lobe may be e 2^-21 off, 5e-3 at e = 1e4: llvmpipe is within it);
#: sqrt inherited from 1 / inversesqrt, 2 ULP then a division's 2.5.
GLSL_450 = FunctionAccuracy(exp_ulps=3.0, exp_ulps_per_x=2.0, log_absolute=2.0**-21, log_ulps=3.0, sqrt_ulps=4.5)

ADAPTERS = [
    Adapter("onnx", ".onnx", _onnx_start, _onnx_run, write=_onnx_write),
    # llvmpipe compiles a material with modules in about a second
    Adapter("glsl", ".glsl", _glsl_start, _glsl_run, functions=GLSL_450, tiers=(Tier.GRID, Tier.EXTREMES),
            skips={"ggx-all-neural": "llvmpipe compiled five materials of GGX's eleven modules for over 3 minutes; "
                                     "ward-all-neural runs every kind of module (term, operator, constant) in GLSL"}),
    # each plugin traces and compiles its own Dr.Jit kernel: 0.3 s a material, seconds with modules
    Adapter("mitsuba", ".json", _mitsuba_start, _mitsuba_run, extra_ops=2, tiers=(Tier.EXTREMES, Tier.FIRST),
            skips={"ggx-all-neural": "the plugin compiled five materials of eleven modules for 70 s (loaded machine); "
                                     "the paper state, the alternatives and Ward all-neural run modules in Mitsuba"}),
]


@pytest.fixture(scope="module", params=ADAPTERS, ids=lambda a: a.name)
def adapter(request):
    """(adapter, its started runtime), once per format."""
    runtime = request.param.start()
    yield request.param, runtime
    if hasattr(runtime, "release"):
        runtime.release()


# -- the cases ------------------------------------------------------------------------------------
def shipped():
    """The shipped enhanced GGX and three of its own materials: the first, the 58th, the last."""
    try:
        model, table = load_model("enhanced-ggx")
    except ValueError:
        pytest.skip("no shipped models/enhanced-ggx in this tree")
    return model, [table.as_params(i).to(torch.float64) for i in (0, 57, len(table.names) - 1)]


CASES = {
    **{name: lambda name=name: (get_model(name), []) for name in available_models()},
    "ggx-paper": lambda: (get_model("ggx", state=PAPER_STATE, seed=2), []),
    "ggx-all-neural": lambda: (get_model("ggx", state="1" * 11, seed=3), []),
    "ggx-alternatives": lambda: (get_model("ggx", alternatives=True, state=ALTERNATIVES_STATE, seed=3), []),
    "ward-all-neural": lambda: (get_model("ward", state="1111111", seed=3), []),
    "enhanced-ggx": shipped,
}


@dataclasses.dataclass
class Material:
    params: MaterialParams
    wi: np.ndarray  # its direction pairs, float32 (what every artifact reads)
    wo: np.ndarray
    above: np.ndarray  # both directions above both horizons
    tier: Tier  # which adapters run it
    _reference: dict = dataclasses.field(default_factory=dict, repr=False)  # what ``reference`` measured

    def reference(self, model, functions: FunctionAccuracy | None) -> tuple[object, Measured, np.ndarray | float]:
        """(its ``SpecializedBRDF``, ``float32_bounds.measure`` of it at the material's directions with
        ``moved_shading``, e_fn for ``functions``), measured once for every adapter."""
        if "measured" not in self._reference:
            special = model.specialize(self.params)
            wi, wo = torch.as_tensor(self.wi), torch.as_tensor(self.wo)
            with torch.no_grad():
                self._reference.update(special=special, measured=measure(
                    lambda i, o: special(i, o).numpy(), lambda i, o: special(i, o).double().numpy(), wi, wo,
                    moved_intermediates=moved_shading))
        special, measured = self._reference["special"], self._reference["measured"]
        if functions is None:
            return special, measured, 0.0
        if functions not in self._reference:
            with torch.no_grad():
                self._reference[functions] = function_error(lambda i, o: special(i, o).numpy(), torch.as_tensor(self.wi),
                                                            torch.as_tensor(self.wo), measured, functions)
        return special, measured, self._reference[functions]


#: The stability grid's extremes, (frame, lobe) indices into test_models' FRAMES and ROUGHNESS: the
#: flat frame with the sharpest lobe, the tilted one with an anisotropic lobe, the most tilted and
#: rotated one with the roughest (f0 = 1 where the model has f0).
EXTREMES = {"alpha": [(0, 0), (1, 2), (2, 4)], "shininess": [(0, 2), (1, 1), (2, 0)]}


def hard_and_random(params: dict[str, np.ndarray], rng, n: int = N_RANDOM) -> tuple[np.ndarray, np.ndarray]:
    """Every hard direction pair of the stability grid about the normal of the material ``params``
    (one row each), then ``n`` random pairs, half of them near its peak."""
    normal = ref.frame(params, 1)[2][0]
    hard = np.array([make(normal) for make in DIRECTIONS.values()])
    wi, wo = random_directions({k: np.repeat(v, n, 0) for k, v in params.items()}, n, rng)
    unit = lambda w: w / np.linalg.norm(w, axis=-1, keepdims=True)  # noqa: E731
    return np.vstack([unit(hard[:, 0]), wi]), np.vstack([unit(hard[:, 1]), wo])


def case_materials(model, shipped_materials: list[MaterialParams], rng) -> list[Material]:
    """Every material of the stability grid on its rows (frame x lobe x f0, ``len(DIRECTIONS)`` rows
    each, in ``stability_grid``'s order), then two random materials and ``shipped_materials`` on
    ``hard_and_random`` pairs."""
    latent = torch.as_tensor(rng.random(model.latent_dim)) if model.uses_latent else None
    wi, wo, _, grid = stability_grid(model)
    lobe = "alpha" if "alpha_x" in model.param_names else "shininess"
    n_f0 = 2 if "f0" in model.param_names else 1
    chosen = []
    for j, start in enumerate(range(0, len(wi), len(DIRECTIONS))):
        rows = slice(start, start + len(DIRECTIONS))
        frame, rough, f0 = j // (len(ROUGHNESS[lobe]) * n_f0), j // n_f0 % len(ROUGHNESS[lobe]), j % n_f0
        params = MaterialParams(torch_params({k: v[start] for k, v in grid.items()}), latent)
        extreme = (frame, rough) in EXTREMES[lobe] and f0 == n_f0 - 1
        chosen.append((params, wi[rows], wo[rows], Tier.EXTREMES if extreme else Tier.GRID))
    randoms = [MaterialParams(torch_params({k: v[0] for k, v in random_params(model, 1, rng).items()}), latent)
               for _ in range(2)]
    for group in (randoms, shipped_materials):
        for i, params in enumerate(group):
            rows = {k: v.double().numpy().reshape(1, -1) for k, v in params.values.items()}
            chosen.append((params, *hard_and_random(rows, rng), Tier.FIRST if i == 0 else Tier.EXTREMES))
    materials = []
    for params, wi, wo, tier in chosen:
        wi32, wo32 = wi.astype(np.float32), wo.astype(np.float32)
        rows = {k: np.broadcast_to(v.double().numpy().reshape(1, -1), (len(wi), v.numel()))
                for k, v in params.values.items()}
        above = above_mask(model, wi32.astype(np.float64), wo32.astype(np.float64), rows)
        materials.append(Material(params, wi32, wo32, above, tier))
    return materials


@pytest.fixture(scope="module", params=list(CASES))
def case(request):
    """(name, model, its materials), built once for every format."""
    model, shipped_materials = CASES[request.param]()
    return request.param, model, case_materials(model, shipped_materials, np.random.default_rng(7))


# -- the contract ---------------------------------------------------------------------------------
def test_the_artifact_equals_the_specialized_evaluator(adapter, case, tmp_path):
    (fmt, runtime), (name, model, materials) = adapter, case
    if name in fmt.skips:
        pytest.skip(fmt.skips[name])
    materials = [m for m in materials if m.tier <= fmt.tiers[model.n_weights() > 0]]
    names = {f"m{i}": m.params for i, m in enumerate(materials)}
    if fmt.write is None:
        export(model, names, fmt.name, tmp_path)
    else:
        fmt.write(model, names, tmp_path)
    got = fmt.run(runtime, [tmp_path / f"{n}{fmt.suffix}" for n in names],
                  [(m.wi, m.wo) for m in materials])
    for i, (m, f) in enumerate(zip(materials, got)):
        what = f"{fmt.name} {name} material {i}"
        assert f.shape == m.wi.shape and np.isfinite(f).all() and (f >= 0).all(), what
        assert (f[~m.above] == 0).all(), f"{what}: not exactly 0 below a horizon"
        special, measured, e_fn = m.reference(model, fmt.functions)
        bound = measured.bound(special.flops_per_evaluation + fmt.extra_ops, fmt.factor, e_fn)
        assert_within(f, measured.truth, bound, what)
