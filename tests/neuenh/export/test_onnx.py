"""The ONNX export (``neuenh.export.onnx``), run for real: every graph executed by onnxruntime.

Layers: (1) the material graphs equal the specialized evaluator: the contract test over every format,
``test_equals_specialized``; (2) the generic graph equals ``evaluate`` with a different material on
every row (the grid's materials, the random and shipped ones, and a random material on each of 4096
more rows), within ``float32_bounds``' arithmetic bound, and (1, width) parameters broadcast; graphs
are valid ONNX with a dynamic batch; (3) ``write``: the files load, carry their metadata, are
reproducible, and a bad material is a one-line ValueError that writes nothing.
"""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch

from neuenh import __version__
from neuenh.export.onnx import OPSET, generic_graph, material_graph, write
from neuenh.materials import LATENT_NAME, MaterialParams
from neuenh.models import available_models
from neuenh.pretrained import load_model
from float32_bounds import assert_within, moved_shading, relative_bound
from test_equals_specialized import CASES as MODELS, case_materials
from test_models import above_mask, random_directions, random_params

CASES = ["enhanced-ggx", "ggx-all-neural", "ggx-alternatives", *available_models()]
ROWS_PER_MATERIAL = 2048  # of each material's pairs, in the generic graph's batch
N_EXTRA = 4096  # more rows, each its own random material


def session(blob: bytes) -> ort.InferenceSession:
    options = ort.SessionOptions()
    options.log_severity_level = 3
    return ort.InferenceSession(blob, options, providers=["CPUExecutionProvider"])


def run(sess: ort.InferenceSession, wi, wo, **params) -> np.ndarray:
    feed = {"wi": np.asarray(wi, dtype=np.float32), "wo": np.asarray(wo, dtype=np.float32)}
    feed.update({k: np.asarray(v, dtype=np.float32) for k, v in params.items()})
    return sess.run(["f_r"], feed)[0]


@pytest.fixture(scope="module", params=CASES)
def exported(request):
    """(case, model, its materials (``test_equals_specialized.case_materials``), its generic graph)."""
    model, shipped = MODELS[request.param]()
    materials = case_materials(model, shipped, np.random.default_rng(sum(map(ord, request.param))))
    return request.param, model, materials, generic_graph(model)


def graph_inputs(params: MaterialParams) -> dict[str, torch.Tensor]:
    """A material's record as the generic graph's named inputs: its values, then its latent code."""
    return {**params.values, **({LATENT_NAME: params.latent} if params.latent is not None else {})}


def test_the_generic_graph_equals_evaluate_with_a_material_per_row(exported):
    """Every material of the case (up to ``ROWS_PER_MATERIAL`` of its rows) and a random material on
    each of ``N_EXTRA`` more rows, in one batch: finite, exactly 0 below either horizon, and within
    ``float32_bounds``' bound of float64 ``evaluate`` (its own float32 path the reference float32 one)."""
    case, model, materials, blob = exported
    sess = session(blob)
    assert [i.name for i in onnx.load_from_string(blob).graph.input] == \
        ["wi", "wo", *model.param_names, *([LATENT_NAME] if model.uses_latent else [])]
    rng = np.random.default_rng(5)
    extra = random_params(model, N_EXTRA, rng)
    if model.uses_latent:
        extra[LATENT_NAME] = rng.random((N_EXTRA, model.latent_dim))
    w_i, w_o = random_directions(extra, N_EXTRA, rng)
    wi = torch.as_tensor(np.vstack([m.wi[:ROWS_PER_MATERIAL] for m in materials] + [w_i]), dtype=torch.float32)
    wo = torch.as_tensor(np.vstack([m.wo[:ROWS_PER_MATERIAL] for m in materials] + [w_o]), dtype=torch.float32)
    inputs = [graph_inputs(m.params) for m in materials]
    rows = {k: np.vstack([np.broadcast_to(i[k].numpy().reshape(1, -1), (len(m.wi[:ROWS_PER_MATERIAL]), i[k].numel()))
                          for m, i in zip(materials, inputs)] + [extra[k]])
            for k in extra}
    rows32 = {k: torch.as_tensor(v, dtype=torch.float32) for k, v in rows.items()}
    got = run(sess, wi, wo, **rows32)
    record = MaterialParams({k: v for k, v in rows32.items() if k != LATENT_NAME}, rows32.get(LATENT_NAME))
    model64, record64 = copy.deepcopy(model).double(), record.to(torch.float64)
    values = {k: v for k, v in rows.items() if k != LATENT_NAME}
    above = above_mask(model, wi.double().numpy(), wo.double().numpy(), values)
    assert got.shape == (len(wi), 3) and np.isfinite(got).all() and (got >= 0).all(), case
    assert (got[~above] == 0).all(), f"{case}: not exactly 0 below a horizon"
    n_ops = max(model.specialize(m.params).flops_per_evaluation for m in materials) + 2 * model.n_weights()
    with torch.no_grad():
        truth, bound = relative_bound(lambda i, o: model64.evaluate(i, o, record64).numpy(),
                                      lambda i, o: model.evaluate(i, o, record).double().numpy(), wi, wo, n_ops,
                                      moved_intermediates=moved_shading)
    assert_within(got, truth, bound, case)

    # one row of parameters serves every sample
    m = materials[-1]
    one = {k: v.numpy().reshape(1, -1) for k, v in graph_inputs(m.params).items()}
    many = {k: np.repeat(v, len(m.wi), 0) for k, v in one.items()}
    np.testing.assert_array_equal(run(sess, m.wi, m.wo, **one), run(sess, m.wi, m.wo, **many))


@pytest.mark.parametrize("n", [1, 0, 7])
def test_graphs_are_valid_onnx_with_a_dynamic_batch(exported, n):
    case, model, materials, blob = exported
    special = model.specialize(materials[-1].params)
    material = material_graph(special, name="m")
    for proto in (onnx.load_from_string(blob), onnx.load_from_string(material)):
        onnx.checker.check_model(proto, full_check=True)
        assert proto.opset_import[0].version == OPSET >= 17
        assert [(d.dim_param, d.dim_value) for d in proto.graph.input[0].type.tensor_type.shape.dim] == [("n", 0), ("", 3)]
        assert [o.name for o in proto.graph.output] == ["f_r"]
    wi, wo = (torch.as_tensor(w[:n]) for w in (materials[-1].wi, materials[-1].wo))
    got = run(session(material), wi, wo)
    assert got.shape == (n, 3)
    np.testing.assert_allclose(got, special(wi, wo).numpy(), rtol=1e-5, atol=1e-6)


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
