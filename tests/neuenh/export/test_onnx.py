"""The ONNX export (``neuenh.export.onnx``), run for real: every graph executed by onnxruntime.

Layers: (1) the material graph against the torch specialized evaluator, for the shipped enhanced
GGX (its own materials), an all-neural GGX (operator modules, a constant module) and every
analytical model, on the stability grid (frames, roughness 1e-4..1, f0 0 and 1, grazing, mirror
peaks up to 1e8, below either horizon) and 4 x 16,384 random pairs per model, half of them near
the peak: finite, exactly 0 below a horizon, equal to torch's float32 to 1e-5 relative where f_r
>= 1e-3 of its max (1e-8 of the max below that) on every row of the grid and on 99.9% of the
random rows where float32 is well conditioned (the grid's ill-conditioned rows to 1e-3: at
roughness-1e-3 peaks an ulp of direction moves f_r by more), and everywhere as close to float64 as torch's
float32 (``Errors``: at roughness-1e-4 peaks an ulp of direction moves the lobe, and two float32
paths are up to a few percent apart, see test_specialize); (2) the generic graph equals
``evaluate`` with a different material on every row, and (1, width) parameters broadcast;
(3) ``write``: the files load, carry their metadata, are reproducible, and a bad material is a
one-line ValueError that writes nothing.
"""

from __future__ import annotations

import copy
import dataclasses
from typing import NamedTuple

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch

from neuenh import __version__
from neuenh.export.onnx import OPSET, generic_graph, material_graph, write
from neuenh.materials import LATENT_NAME, MaterialParams
from neuenh.models import available_models, get_model
from neuenh.pretrained import load_model
from test_models import above_mask, random_directions, random_params, stability_grid, torch_params
from test_specialize import materials_of

from ggx_states import ALTERNATIVES_STATE

N_RANDOM = 16_384  # random pairs per random material; 4 per model
N_RANDOM_ALL_NEURAL = 4_096  # eleven modules: this model adds operator and constant modules, not pairs
CASES = ["enhanced-ggx", "ggx-all-neural", "ggx-alternatives", *available_models()]


def session(blob: bytes) -> ort.InferenceSession:
    options = ort.SessionOptions()
    options.log_severity_level = 3
    return ort.InferenceSession(blob, options, providers=["CPUExecutionProvider"])


def run(sess: ort.InferenceSession, wi, wo, **params) -> np.ndarray:
    feed = {"wi": np.asarray(wi, dtype=np.float32), "wo": np.asarray(wo, dtype=np.float32)}
    feed.update({k: np.asarray(v, dtype=np.float32) for k, v in params.items()})
    return sess.run(["f_r"], feed)[0]


class Material(NamedTuple):
    params: MaterialParams  # what specialize takes
    special: object  # its SpecializedBRDF
    session: ort.InferenceSession  # its material graph
    wi: np.ndarray  # its direction pairs, float64
    wo: np.ndarray
    above: np.ndarray | None  # above both horizons (the stability grid's rows) or None


def build(case: str):
    """(model, latent of its materials or None, the shipped materials' parameters)."""
    if case == "enhanced-ggx":
        model, table = load_model("enhanced-ggx")
        return model, table.latent[0].detach().double(), [table.as_params(i) for i in (0, 57)]
    if case == "ggx-all-neural":  # every position neural: operator modules, M a constant module
        model = get_model("ggx", state="1" * 11, seed=3)
        return model, torch.as_tensor(np.random.default_rng(0).random(27)), []
    if case == "ggx-alternatives":  # alternative terms (RGB Fresnel, Oren-Nayar) beside a module
        model = get_model("ggx", alternatives=True, state=ALTERNATIVES_STATE, seed=3)
        return model, torch.as_tensor(np.random.default_rng(1).random(27)), []
    return get_model(case), None, []


@pytest.fixture(scope="module", params=CASES)
def exported(request):
    """(case, model, its materials, its generic graph): the stability grid's materials, and 4 random
    ones (2 of them the shipped model's own), each specialized and exported once."""
    model, latent, shipped = build(request.param)
    rng = np.random.default_rng(sum(map(ord, request.param)))
    wi, wo, _, grid = stability_grid(model)
    materials = []

    def add(params, wi, wo, above):
        special = model.specialize(params)
        materials.append(Material(params, special, session(material_graph(special)), wi, wo, above))

    for one, rows in materials_of(grid):
        params = MaterialParams(torch_params(one), latent)
        add(params, wi[rows], wo[rows], above_mask(model, wi[rows], wo[rows], {k: v[rows] for k, v in grid.items()}))
    randoms = [MaterialParams(torch_params({k: v[0] for k, v in random_params(model, 1, rng).items()}), latent)
               for _ in range(4 - len(shipped))]
    n = N_RANDOM_ALL_NEURAL if request.param == "ggx-all-neural" else N_RANDOM
    for params in randoms + [p.to(torch.float64) for p in shipped]:
        rows = {k: np.broadcast_to(v.numpy().reshape(1, -1), (n, v.numel())) for k, v in params.values.items()}
        add(params, *random_directions(rows, n, rng), None)
    return request.param, model, materials, generic_graph(model)


def graph_inputs(params: MaterialParams) -> dict[str, torch.Tensor]:
    """A material's record as the generic graph's named inputs: its values, then its latent code."""
    return {**params.values, **({LATENT_NAME: params.latent} if params.latent is not None else {})}


def relative_errors(got, want, floor: float) -> np.ndarray:
    return np.abs(np.asarray(got, np.float64) - want) / np.maximum(np.abs(want), floor)


def nudge(w: torch.Tensor, seed: int) -> torch.Tensor:
    """``w`` moved by 2 float32 ulps per component (random signs), renormalized."""
    sign = torch.randint(0, 2, w.shape, generator=torch.Generator().manual_seed(seed), dtype=torch.float64) * 2 - 1
    return torch.nn.functional.normalize(w * (1 + sign * 2.0**-23), dim=1)


class Errors:
    """onnxruntime's float32 against torch's float32 and float64 ``evaluate``, one batch at a time:

    * finite, >= 0 and exactly 0 wherever float64 is 0 (below a horizon) or ``below`` says so;
    * 1e-5 relative from torch's float32 where f_r >= 1e-3 of its max (1e-8 of the max below that):
      on every row with ``every_row`` (the stability grid), else kept for ``check_conditioned``
      on the rows where float32 is well conditioned (2 ulps of direction move f_r by < 1e-6 and
      torch's float32 is within 1e-6 of float64);
    * as close to float64 as torch's float32: the error's 99th percentile within twice torch's (or
      1e-5), its maximum within 4 times (or 1e-4). At sharp peaks and high exponents an ulp of
      direction or of exp, log, pow, Gemm moves f_r by up to a few percent, differently in the two
      float32 paths (as between ``evaluate`` and the specialized evaluator, test_specialize)."""

    def __init__(self):
        self.pairs, self.conditioned = 0, []

    def check(self, what, got, torch32, float64, wi32, wo32, below=None, every_row=False):
        """``float64(wi, wo)``: the torch model in float64, f_r (n, 3) as numpy."""
        truth = float64(wi32.double(), wo32.double())
        nudged = float64(*(nudge(w.double(), seed) for seed, w in enumerate((wi32, wo32))))
        assert got.shape == (len(wi32), 3) and got.dtype == np.float32 and np.isfinite(got).all(), what
        below = (truth == 0).all(1) if below is None else below
        assert (got[below] == 0).all() and (got >= 0).all(), f"{what}: not exactly 0 below a horizon"
        floor = 1e-3 * float(np.abs(truth).max())
        error = relative_errors(got, torch32, floor).max(1)
        fine = (relative_errors(nudged, truth, floor) <= 1e-6).all(1) & \
            (relative_errors(torch32, truth, floor) <= 1e-6).all(1)
        if every_row:  # every well-conditioned row of the grid to 1e-5; the ill-conditioned ones to 1e-3
            assert error[fine].max(initial=0.0) <= 1e-5 and error.max() <= 1e-3, \
                f"{what}: {error[fine].max(initial=0.0):.3g} (conditioned), {error.max():.3g} relative from torch's float32"
        self.conditioned.append(error[fine])
        ours, theirs = relative_errors(got, truth, floor), relative_errors(torch32, truth, floor)
        for q, factor, slack in ((0.99, 2, 1e-5), (1.0, 4, 1e-4)):
            mine, torchs = float(np.quantile(ours, q)), float(np.quantile(theirs, q))
            assert mine <= max(slack, factor * torchs), \
                f"{what}: {q:.0%} quantile of the error {mine:.3g}, torch's float32 {torchs:.3g}"
        self.pairs += len(wi32)

    def check_conditioned(self, what):
        """1e-5 on 99.9% of the well-conditioned rows (and 1e-3 on all: a wrong graph is far off)."""
        errors = np.concatenate(self.conditioned)
        assert len(errors) >= 0.6 * self.pairs, f"{what}: only {len(errors)} of {self.pairs} rows well conditioned"
        assert np.quantile(errors, 0.999) <= 1e-5 and errors.max() <= 1e-3, \
            f"{what}: {np.quantile(errors, 0.999):.3g} (99.9%), {errors.max():.3g} (max) from torch's float32"


def test_the_material_graph_equals_the_torch_evaluators(exported):
    case, model, materials, _ = exported
    errors = Errors()
    for m in materials:
        wi32, wo32 = (torch.as_tensor(w, dtype=torch.float32) for w in (m.wi, m.wo))
        what = f"{case} {({k: v.tolist() for k, v in m.params.values.items()})}"
        # float64: the specialized evaluator's own float64 kernel, = evaluate to 1e-9 (test_specialize)
        errors.check(what, run(m.session, wi32, wo32), m.special(wi32, wo32).numpy(),
                     lambda i, o, special=m.special: special(i, o).numpy(), wi32, wo32,
                     below=None if m.above is None else ~m.above, every_row=m.above is not None)
    assert errors.pairs >= (16_384 if case == "ggx-all-neural" else 65_536)
    errors.check_conditioned(case)


def test_the_generic_graph_equals_evaluate_with_a_material_per_row(exported):
    """Every material of the set (up to 2048 of its rows) and a random material on each of 4096 more
    rows, in one batch: the generic graph against ``evaluate`` as the material graph against the
    specialized evaluator."""
    case, model, materials, blob = exported
    sess = session(blob)
    assert [i.name for i in onnx.load_from_string(blob).graph.input] == \
        ["wi", "wo", *model.param_names, *([LATENT_NAME] if model.uses_latent else [])]
    rng = np.random.default_rng(5)
    extra = random_params(model, 4096, rng)
    if model.uses_latent:
        extra[LATENT_NAME] = rng.random((4096, model.latent_dim))
    w_i, w_o = random_directions(extra, 4096, rng)
    wi = torch.as_tensor(np.vstack([m.wi[:2048] for m in materials] + [w_i]), dtype=torch.float32)
    wo = torch.as_tensor(np.vstack([m.wo[:2048] for m in materials] + [w_o]), dtype=torch.float32)
    inputs = [graph_inputs(m.params) for m in materials]
    rows = {k: np.vstack([np.broadcast_to(i[k].numpy().reshape(1, -1), (len(m.wi[:2048]), i[k].numel()))
                          for m, i in zip(materials, inputs)] + [extra[k]])
            for k in extra}
    rows32 = {k: torch.as_tensor(v, dtype=torch.float32) for k, v in rows.items()}
    got = run(sess, wi, wo, **rows32)
    record = MaterialParams({k: v for k, v in rows32.items() if k != LATENT_NAME}, rows32.get(LATENT_NAME))
    model64 = copy.deepcopy(model).double()
    with torch.no_grad():
        want = model.evaluate(wi, wo, record).numpy()
        errors = Errors()
        errors.check(case, got, want, lambda i, o: model64.evaluate(i, o, record.to(torch.float64)).numpy(), wi, wo)
    errors.check_conditioned(case)

    # one row of parameters serves every sample
    m = materials[-1]
    one = {k: v.numpy().reshape(1, -1) for k, v in graph_inputs(m.params).items()}
    many = {k: np.repeat(v, len(m.wi), 0) for k, v in one.items()}
    np.testing.assert_array_equal(run(sess, m.wi, m.wo, **one), run(sess, m.wi, m.wo, **many))


@pytest.mark.parametrize("n", [1, 0, 7])
def test_graphs_are_valid_onnx_with_a_dynamic_batch(exported, n):
    case, model, materials, blob = exported
    m = materials[-1]
    for proto in (onnx.load_from_string(blob), onnx.load_from_string(material_graph(m.special, name="m"))):
        onnx.checker.check_model(proto, full_check=True)
        assert proto.opset_import[0].version == OPSET >= 17
        assert [(d.dim_param, d.dim_value) for d in proto.graph.input[0].type.tensor_type.shape.dim] == [("n", 0), ("", 3)]
        assert [o.name for o in proto.graph.output] == ["f_r"]
    wi, wo = (torch.as_tensor(w[:n], dtype=torch.float32) for w in (m.wi, m.wo))
    got = run(m.session, wi, wo)
    assert got.shape == (n, 3)
    np.testing.assert_allclose(got, m.special(wi, wo).numpy(), rtol=1e-5, atol=1e-6)


# -- write ---------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def shipped():
    model, table = load_model("enhanced-ggx")
    return model, {"alum-bronze": table.as_params(0), "my paint/2": table.as_params(57)}


def test_write_gives_loadable_files_with_their_metadata(shipped, tmp_path):
    model, materials = shipped
    paths = write(model, materials, tmp_path / "out")
    assert [p.name for p in paths] == ["alum-bronze.onnx", "my_paint_2.onnx", "ggx-generic.onnx"]
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == sorted(p.name for p in paths)  # no temp file left
    for path, name in zip(paths, [*materials, None]):
        sess = session(path.read_bytes())
        meta = sess.get_modelmeta().custom_metadata_map
        assert meta["model"] == "ggx" and meta["state"] == model.state and meta["formula"] == model.describe()
        assert meta["neuenh_version"] == __version__ and meta.get("material") == name
        assert (LATENT_NAME in meta["inputs"]) == (name is None) and sess.get_modelmeta().producer_name == "neuenh"
        if name is not None:
            rng = np.random.default_rng(1)
            wi, wo = random_directions({k: v.numpy().reshape(1, -1).repeat(64, 0)
                                        for k, v in materials[name].values.items()}, 64, rng)
            wi32, wo32 = (torch.as_tensor(w, dtype=torch.float32) for w in (wi, wo))
            want = model.specialize(materials[name])(wi32, wo32).numpy()
            # the files run (accuracy is the tests above: near a sharp peak two float32 paths part by 2e-4)
            np.testing.assert_allclose(run(sess, wi32, wo32), want, rtol=1e-3, atol=1e-5 * float(want.max()))
    before = [p.read_bytes() for p in paths]
    assert [p.read_bytes() for p in write(model, materials, tmp_path / "out")] == before  # reproducible


@pytest.mark.parametrize("names, message", [
    (["a b", "a_b"], r"material 'a_b' would be written to a_b.onnx, as material 'a b'"),
    (["Gold", "gold"], r"gold.onnx, as material 'Gold'"),
    (["ggx-generic"], r"ggx-generic.onnx, as the generic model's"),
    (["../"], r"nothing usable as a file name"),
    (["rough"], r"material 'rough': parameter 'alpha_x' must lie in"),
])
def test_a_bad_material_is_a_one_line_value_error_that_writes_nothing(shipped, tmp_path, names, message):
    model, materials = shipped
    params = next(iter(materials.values()))
    given = {name: dataclasses.replace(params, values={**params.values, "alpha_x": torch.tensor([5.0])})
             if name == "rough" else params for name in names}
    with pytest.raises(ValueError, match=message) as error:
        write(model, given, tmp_path / "out")
    assert "\n" not in str(error.value)
    assert not (tmp_path / "out").exists()
