"""``neuenh export`` as a user runs it: fit a measured material with the shipped model, export it,
and run what was written in its real runtime; bad inputs are one-line errors (exit 2)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from neuenh.data.synthetic import synthetic_ggx
from neuenh.data.table import write_table
from neuenh.materials import MaterialParams
from neuenh.pretrained import bundle_path, load_model
from cli_runs import neuenh, neuenh_here

pytestmark = pytest.mark.skipif(bundle_path("enhanced-ggx") is None, reason="no shipped models/enhanced-ggx in this tree")


def one_line_error(out, *fragments):
    assert out.returncode == 2 and "Traceback" not in out.stderr, out.stderr
    [line] = out.stderr.strip().splitlines()
    assert line.startswith("neuenh export: error: ") and all(f in line for f in fragments), line


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """A measured (synthetic GGX) material fitted with the shipped model at the latent capacity (its
    modules in every export; at the default, auto, a noiseless GGX material keeps plain GGX): the
    report and the bundle."""
    where = tmp_path_factory.mktemp("fit")
    (material,) = synthetic_ggx(1, seed=11, noise_sigma=0.0)
    table = write_table(where / "brushed steel.npz", *material.samples(500, seed=0))
    out = neuenh_here("fit", "--model", "enhanced-ggx", table, "--capacity", "latent", "--epochs", "5", "--json",
                      "-o", where / "bundle")
    assert out.returncode == 0, out.stderr
    (where / "fit.json").write_text(out.stdout)
    return where / "fit.json", where / "bundle"


def test_a_fit_report_exports_to_glsl_that_runs_on_llvmpipe(fitted, tmp_path):
    from gl_runtime import gl_context, run_brdf  # tests/gl_runtime.py

    report, _ = fitted
    out = neuenh("export", "enhanced-ggx", "--params", report, "--format", "glsl", "-o", tmp_path / "glsl")
    assert out.returncode == 0, out.stderr
    path, generic = [Path(line) for line in out.stdout.split()]
    assert path == tmp_path / "glsl" / "brushed_steel.glsl" and path.stat().st_mode & 0o777 == 0o644
    assert generic.name == "ggx-generic.glsl"

    model, _ = load_model("enhanced-ggx")
    params = MaterialParams.from_json(json.loads(report.read_text())["materials"][0])
    rng = np.random.default_rng(0)
    wi, wo = (np.abs(rng.normal(size=(4096, 3))) for _ in range(2))
    wi, wo = ((w / np.linalg.norm(w, axis=1, keepdims=True)).astype(np.float32) for w in (wi, wo))
    ctx = gl_context()
    try:
        got = run_brdf(ctx, path.read_text(), wi, wo)
    finally:
        ctx.release()
    want = model.specialize(params)(torch.as_tensor(wi, dtype=torch.float64), torch.as_tensor(wo, dtype=torch.float64))
    want = want.numpy()
    error = np.abs(got - want) / np.maximum(np.abs(want), 1e-3 * want.max())
    assert error.max() < 1e-4


def test_a_fitted_bundle_exports_its_own_materials(fitted, tmp_path):
    _, bundle = fitted
    out = neuenh_here("export", bundle, "--format", "glsl", "-o", tmp_path)
    assert out.returncode == 0, out.stderr
    assert [Path(p).name for p in out.stdout.split()] == ["brushed_steel.glsl", "ggx-generic.glsl"]


def test_bad_inputs_are_one_line_errors(fitted, tmp_path):
    """In this process (``neuenh_here``): each is refused before any work; the entry point's own
    handling of errors is what the fresh-process tests above and below run through."""
    report, bundle = fitted
    plain = tmp_path / "plain.json"
    plain.write_text(report.read_text().replace('"state": "', '"state": "x'))
    one_line_error(neuenh_here("export", "enhanced-ggx", "--params", plain, "--format", "glsl", "-o", tmp_path),
                   "is a fit of ggx in state x", "give the model it was fitted with")
    one_line_error(neuenh_here("export", bundle, "--format", "glsl", "--material", "gold", "-o", tmp_path),
                   "no material 'gold'; there are: brushed steel")
    one_line_error(neuenh_here("export", "ggx", "--format", "glsl", "-o", tmp_path), "ggx holds no materials")
    one_line_error(neuenh_here("export", report, "--format", "glsl", "-o", tmp_path),
                   "nor a bundle folder; a fit report", f"neuenh export MODEL --params {report}")
    (tmp_path / "junk.json").write_text("{")
    one_line_error(neuenh_here("export", "ggx", "--params", tmp_path / "junk.json", "--format", "glsl",
                               "-o", tmp_path), "not a fit report")
    out = neuenh_here("export", "ggx", "--format", "renderman", "-o", tmp_path)
    assert out.returncode == 2 and "invalid choice: 'renderman'" in out.stderr
    one_line_error(neuenh_here("export", "--format", "glsl", "-o", tmp_path), "give a MODEL or --plan")
    one_line_error(neuenh_here("export", "--plan", tmp_path / "none.json", "--format", "glsl", "-o", tmp_path),
                   "none.json: no such file")
    one_line_error(neuenh_here("export", "--plan", tmp_path, "--format", "glsl", "-o", tmp_path / "out"),
                   "a folder, not a scene plan (give its plan.json)")
    assert list(tmp_path.glob("*.glsl")) == []  # nothing half-written


@pytest.fixture(scope="module")
def plan(tmp_path_factory):
    """A scene plan over a searched model's rungs (the analytical start, then invE neural), written
    by neuenh scene plan, with one material's choice moved to the module rung (whatever its error)."""
    import yaml

    from neuenh.checkpoint import Bundle, Rung
    from scene_files import write_tables

    where = tmp_path_factory.mktemp("plan")
    tables = write_tables(where)
    bundle = Bundle.initial("ggx", ["a"])
    plain = Bundle(bundle.model, bundle.materials)
    bundle.model = bundle.model.enhance("00000100000", seed=1)
    bundle.rungs = [Rung.of(0, 0.03, plain), Rung.of(1, 0.02, bundle)]
    bundle.save(where / "searched")
    scene = {"materials": [{"path": str(tables / "gloss.npz")}, {"path": str(tables / "retro.npz")}],
             "ladder": [{"rungs": str(where / "searched")}], "tolerance": {"relative": 0.1},
             "fit": {"samples": 300, "test_samples": 200, "epochs": 20}}
    (where / "scene.yaml").write_text(yaml.safe_dump(scene))
    out = neuenh("scene", "plan", where / "scene.yaml", "-o", where / "plan", "--no-sheet")
    assert out.returncode == 0, out.stderr
    data = json.loads((where / "plan" / "plan.json").read_text())
    module_rung = data["ladder"][1]
    retro = data["materials"][1]
    retro["chosen"], retro["params"] = module_rung["key"], retro["results"][1]["params"]
    (where / "plan" / "plan.json").write_text(json.dumps(data))
    bundle.save(where / "plan" / "bundles" / "searched")  # as the plan writes the bundles of the rungs it uses
    return where / "plan" / "plan.json", data


def test_a_plan_exports_each_material_with_its_rung_and_only_its_modules(plan, tmp_path):
    import onnxruntime as ort

    from neuenh.scene.outputs import safe_name

    path, data = plan
    out = neuenh_here("export", "--plan", path, "--format", "onnx", "-o", tmp_path)
    assert out.returncode == 0, out.stderr
    gloss_rung, retro_rung = (m["chosen"] for m in data["materials"])
    assert (tmp_path / safe_name(gloss_rung) / "gloss.onnx").exists() or gloss_rung == retro_rung
    retro = tmp_path / safe_name(retro_rung) / "retro.onnx"
    session = ort.InferenceSession(retro.read_bytes(), providers=["CPUExecutionProvider"])
    model = Bundle_rung(path, retro_rung)
    params = MaterialParams.from_json(data["materials"][1]["params"])
    rng = np.random.default_rng(0)
    wi, wo = ((w / np.linalg.norm(w, axis=1, keepdims=True)).astype(np.float32)
              for w in (np.abs(rng.normal(size=(512, 3))) for _ in range(2)))
    got = session.run(["f_r"], {"wi": wi, "wo": wo})[0]
    want = model.specialize(params)(torch.as_tensor(wi), torch.as_tensor(wo)).numpy()
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-6)
    assert model.state == "00000100000" and len(model.neural) == 1  # the module rung, with its one module


def Bundle_rung(plan_json: Path, key: str):
    from neuenh.checkpoint import Bundle

    [rung] = [r for r in Bundle.load(plan_json.parent / "bundles" / "searched").rungs if key.endswith(r.state)]
    return rung.model


def test_a_plan_without_its_bundle_is_a_one_line_error(plan, tmp_path):
    import shutil

    path, _ = plan
    copy = tmp_path / "plan"
    shutil.copytree(path.parent, copy)
    shutil.rmtree(copy / "bundles")
    one_line_error(neuenh_here("export", "--plan", copy / "plan.json", "--format", "glsl", "-o", tmp_path / "o"),
                   "needs its bundle")


def test_a_plan_writes_the_materials_planned_with_nbrdf_from_their_networks(plan, tmp_path):
    """A material the plan gave the per-material NBRDF rung is written from its network into
    ``OUT/nbrdf/``, and the file runs in onnxruntime as that network; ``--material`` picks it; a plan
    whose NBRDF weights are not a network's is a one-line error naming the material."""
    import onnxruntime as ort

    from neuenh.scene.outputs import safe_name
    from neuenh.study.nbrdf_fit import NBRDFNetwork

    path, data = plan
    data = json.loads(path.read_text())
    net = NBRDFNetwork(seed=4)
    data["ladder"].append({"key": "nbrdf", "label": "NBRDF", "model": "nbrdf", "state": None, "shared_weights": 0})
    data["materials"][0].update(chosen="nbrdf", params=net.state())
    copy = path.parent / "with-nbrdf.json"  # beside the plan's bundles
    copy.write_text(json.dumps(data))
    out = neuenh_here("export", "--plan", copy, "--format", "onnx", "-o", tmp_path / "all")
    assert out.returncode == 0, out.stderr
    written = sorted(p.relative_to(tmp_path / "all").as_posix() for p in (tmp_path / "all").rglob("*.onnx"))
    assert written == sorted(["nbrdf/gloss.onnx", f"{safe_name(data['materials'][1]['chosen'])}/retro.onnx",
                              f"{safe_name(data['materials'][1]['chosen'])}/ggx-generic.onnx"]), written
    session = ort.InferenceSession(str(tmp_path / "all" / "nbrdf" / "gloss.onnx"), providers=["CPUExecutionProvider"])
    rng = np.random.default_rng(0)
    wi, wo = ((w / np.linalg.norm(w, axis=1, keepdims=True)).astype(np.float32)
              for w in (np.abs(rng.normal(size=(512, 3))) for _ in range(2)))
    want = net.evaluate(torch.as_tensor(wi), torch.as_tensor(wo)).numpy()
    np.testing.assert_allclose(session.run(["f_r"], {"wi": wi, "wo": wo})[0], want, rtol=1e-4, atol=1e-6)
    # (the export's own bound is test_nbrdf_export's; this checks the plan's weights reach the right file)

    out = neuenh_here("export", "--plan", copy, "--format", "glsl", "--material", "gloss", "-o", tmp_path / "one")
    assert out.returncode == 0, out.stderr
    assert [p.name for p in (tmp_path / "one").rglob("*.glsl")] == ["gloss.glsl"]
    data["materials"][0]["params"] = {"layers.0.weight": [0.0] * 7}
    copy.write_text(json.dumps(data))
    one_line_error(neuenh_here("export", "--plan", copy, "--format", "glsl", "-o", tmp_path / "bad"),
                   "material 'gloss': not the weights of an NBRDF network")
    assert not (tmp_path / "bad").exists() or not any((tmp_path / "bad").rglob("*.glsl"))


def test_a_file_of_nbrdf_networks_exports_each_network_as_a_material(tmp_path):
    """``neuenh export NBRDF.npz``: every network (or ``--material``'s) into one folder, each file the
    network the reader (``neuenh.data.nbrdf``) evaluates; misuses are one-line errors."""
    import onnxruntime as ort

    from data_files import nbrdf_weights
    from neuenh.data.nbrdf import nbrdf_material

    weights = tmp_path / "networks.npz"
    np.savez(weights, **nbrdf_weights(["red paint", "felt"], seed=3))
    out = neuenh_here("export", weights, "--format", "onnx", "-o", tmp_path / "all")
    assert out.returncode == 0, out.stderr
    assert sorted(p.name for p in (tmp_path / "all").iterdir()) == ["felt.onnx", "red_paint.onnx"]
    rng = np.random.default_rng(1)
    wi, wo = ((w / np.linalg.norm(w, axis=1, keepdims=True)).astype(np.float32)
              for w in (np.abs(rng.normal(size=(512, 3))) for _ in range(2)))
    session = ort.InferenceSession(str(tmp_path / "all" / "red_paint.onnx"), providers=["CPUExecutionProvider"])
    want = nbrdf_material(weights, "red paint").evaluate(torch.as_tensor(wi), torch.as_tensor(wo)).numpy()
    np.testing.assert_allclose(session.run(["f_r"], {"wi": wi, "wo": wo})[0], want, rtol=1e-4, atol=1e-6 * want.max())
    # (the format's own bound is test_nbrdf_export's; this checks which network reaches which file)

    out = neuenh_here("export", weights, "--format", "glsl", "--material", "felt", "-o", tmp_path / "one")
    assert out.returncode == 0, out.stderr
    assert [p.name for p in (tmp_path / "one").iterdir()] == ["felt.glsl"]
    one_line_error(neuenh_here("export", weights, "--format", "glsl", "--material", "gold", "-o", tmp_path / "x"),
                   "gold")
    one_line_error(neuenh_here("export", weights, "--format", "glsl", "--params", weights, "-o", tmp_path / "y"),
                   "--params goes with a model")


@pytest.fixture(scope="module")
def own_capacity_plan(tmp_path_factory):
    """A scene plan (written in-process) whose rungs fit a model with a module at capacities of their
    own: ``original`` (plain GGX in the module's place) and ``last-layer`` (per-material corrections
    of the module's last layer); gloss is given the first, retro the second."""
    from neuenh.scene import parse_scene, plan_scene
    from neuenh.scene.outputs import write_plan
    from scene_files import scene, write_module_bundle, write_tables

    where = tmp_path_factory.mktemp("capacities")
    tables = write_tables(where)
    searched = write_module_bundle(where / "searched")
    ladder = [{"model": str(where / "searched"), "capacity": c} for c in ("original", "last-layer")]
    fit = {"samples": 300, "test_samples": 200, "epochs": 20}
    plan = plan_scene(parse_scene(scene(tables, ladder=ladder, fit=fit)), tables)
    gloss, retro = plan.materials
    gloss.chosen, retro.chosen = (r["key"] for r in plan.ladder)
    write_plan(plan, where / "plan", sheet=False)
    return where / "plan" / "plan.json", searched, where / "searched"


def _onnx_f_r(path: Path, n: int = 512) -> tuple[np.ndarray, torch.Tensor, torch.Tensor]:
    import onnxruntime as ort

    rng = np.random.default_rng(0)
    wi, wo = ((w / np.linalg.norm(w, axis=1, keepdims=True)).astype(np.float32)
              for w in (np.abs(rng.normal(size=(n, 3))) for _ in range(2)))
    session = ort.InferenceSession(path.read_bytes(), providers=["CPUExecutionProvider"])
    return session.run(["f_r"], {"wi": wi, "wo": wo})[0], torch.as_tensor(wi), torch.as_tensor(wo)


def _plain_ggx(record: dict, wi: torch.Tensor, wo: torch.Tensor) -> np.ndarray:
    """f_r of plain GGX (built here, not the exporter's model) with a record's analytical values."""
    from neuenh.models import get_model

    return get_model("ggx").specialize({k: torch.tensor(v) for k, v in record["params"].items()})(wi, wo).numpy()


def test_a_plan_exports_an_analytical_capacity_with_its_own_model_and_corrections_with_theirs(own_capacity_plan,
                                                                                               tmp_path):
    from neuenh.scene.outputs import safe_name

    path, searched, _ = own_capacity_plan
    data = json.loads(path.read_text())
    gloss, retro = data["materials"]
    assert [gloss["params"]["capacity"], retro["params"]["capacity"]] == ["original", "last-layer"]
    assert retro["params"]["corrections"] and retro["params"]["params_per_material"] > searched.n_material_params()
    out = neuenh_here("export", "--plan", path, "--format", "onnx", "-o", tmp_path)
    assert out.returncode == 0, out.stderr
    # gloss: plain GGX (built here from its recorded values), in its capacity's folder inside its rung's
    got, wi, wo = _onnx_f_r(tmp_path / safe_name(gloss["chosen"]) / "original" / "gloss.onnx")
    np.testing.assert_allclose(got, _plain_ggx(gloss["params"], wi, wo), rtol=1e-4, atol=1e-6)
    # retro: the searched model with its corrections folded in (without them it is another BRDF)
    got, wi, wo = _onnx_f_r(tmp_path / safe_name(retro["chosen"]) / "retro.onnx")
    params = MaterialParams.from_json(retro["params"])
    want = searched.specialize(params)(wi, wo).numpy()
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-6)
    bare = searched.specialize(MaterialParams(params.values, params.latent))(wi, wo).numpy()
    assert np.abs(bare - want).max() > 1e-3 * np.abs(want).max()


def test_a_fit_report_exports_an_analytical_capacity_into_its_capacitys_folder(own_capacity_plan, tmp_path):
    path, searched, folder = own_capacity_plan
    gloss = json.loads(path.read_text())["materials"][0]
    report = {"model": searched.name, "state": searched.state, "materials": [{"name": "gloss", **gloss["params"]}]}
    (tmp_path / "fit.json").write_text(json.dumps(report))  # as neuenh fit --capacity original --json writes it
    out = neuenh_here("export", folder, "--params", tmp_path / "fit.json", "--format", "onnx", "-o", tmp_path / "out")
    assert out.returncode == 0, out.stderr
    assert not (tmp_path / "out" / "gloss.onnx").exists()
    got, wi, wo = _onnx_f_r(tmp_path / "out" / "original" / "gloss.onnx")
    np.testing.assert_allclose(got, _plain_ggx(gloss["params"], wi, wo), rtol=1e-4, atol=1e-6)
