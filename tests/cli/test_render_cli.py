"""``neuenh render`` as a user runs it (exit codes, files, JSON, one-line errors), and the procedural
studio environment.

Every command line runs once in one module fixture, and the tests read their results: one of them in
a fresh process, as a user runs it, the others in this process (``tests/cli_runs.py``: the same code
from the parsed arguments on, without an interpreter's start, which is most of a small render's cost).
"""

import json
import os
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from neuenh.data.exr import read_rgb_exr
from neuenh.render import EnvironmentMap
from neuenh.render.envmaps import KEY_LIGHT, RIM_LIGHT, studio_environment
from cli_runs import neuenh, neuenh_here

RGL = Path(__file__).resolve().parents[3] / "shared" / "data" / "rgl" / "paper_white_rgb.bsdf"
SIZE, SAMPLES = 48, 8
SMALL = ["--size", SIZE, "--samples", SAMPLES, "--threads", 1]

GGX = {"normal": [0, 0], "t_theta": [0], "rho_d": [0.3, 0.2, 0.1], "rho_s": [0.4, 0.4, 0.4],
       "alpha_x": [0.2], "alpha_y": [0.3], "f0": [0.6]}
MATTE = {**GGX, "rho_d": [0.8, 0.8, 0.8], "rho_s": [0, 0, 0]}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """name -> (CompletedProcess, output directory) of every command line."""
    tmp = tmp_path_factory.mktemp("render")
    params = tmp / "fit.json"  # the `neuenh fit --json` format
    params.write_text(json.dumps({"model": "ggx", "materials": [
        {"name": "matte", "loss": 0.0, "params": MATTE}, {"name": "glossy", "loss": 0.0, "params": GGX}]}))
    (tmp / "overwrite").mkdir()  # a directory holding an earlier render's file
    (tmp / "overwrite" / "model.png").write_bytes(b"earlier")
    lines = {
        "identity": ["--truth-model", "ggx", "--model", "ggx", "--json"],
        "directional": ["--model", "ggx", "--params", params, "--light", "1,0,0:2,2,2", "--force", "--json"],
        "bad-light": ["--light", "1,2:3"],
    }
    if RGL.is_file():
        lines["rgl"] = ["--truth", RGL, "--model", "ggx", "--json"]
    outputs = {name: tmp / ("overwrite" if name == "directional" else name) for name in lines}
    run = {name: neuenh if name == "identity" else neuenh_here for name in lines}
    return {name: (run[name]("render", *args, *SMALL, "-o", outputs[name]), outputs[name])
            for name, args in lines.items()}


def ok(result):
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)


def test_an_analytical_model_renders_under_the_studio(runs):
    result, out = runs["identity"]
    report = ok(result)
    assert report["model"]["params_from"].startswith("initial values")
    assert report["model"]["params"]["rho_d"] == [0.5, 0.5, 0.5]  # the mean of the range [0, 1]
    assert report["lighting"]["environment"] == "studio" and report["lighting"]["samples"] == SAMPLES**2
    assert json.loads((out / "render.json").read_text()) == report
    image = read_rgb_exr(out / "model.exr")
    assert image.shape == (SIZE, SIZE, 3) and np.isfinite(image).all() and image.min() >= 0
    # the key light is up and to the right: that side of the sphere is brighter
    assert image[:, SIZE // 2:].mean() > image[:, :SIZE // 2].mean()
    assert image[:SIZE // 2].mean() > image[SIZE // 2:].mean()
    from matplotlib.image import imread

    png = imread(out / "model.png")
    assert png.shape[:2] == (SIZE, SIZE) and png[..., :3].std() > 0.05 and png[..., :3].max() > 0.5


def test_the_same_model_as_truth_and_model_is_identical(runs):
    result, out = runs["identity"]
    report = ok(result)
    assert report["truth"]["params"] == report["model"]["params"]
    assert report["metrics"]["ssim"] == 1.0 and report["metrics"]["delta_e_itp"] == 0.0
    assert sorted(p.name for p in out.iterdir()) == sorted(
        ["model.exr", "model.png", "truth.exr", "truth.png", "error.png", "render.json"])
    np.testing.assert_array_equal(read_rgb_exr(out / "truth.exr"), read_rgb_exr(out / "model.exr"))


def test_measured_truth_against_a_default_ggx(runs):
    if "rgl" not in runs:
        pytest.skip(f"the RGL measurements are not here ({RGL})")
    result, out = runs["rgl"]
    report = ok(result)
    assert report["truth"]["measured"] == str(RGL) and report["truth"]["material"] == "paper_white_rgb"
    m = report["metrics"]
    assert 0 < m["ssim"] < 1 and m["delta_e_itp"] > 0
    assert json.loads((out / "render.json").read_text())["metrics"] == m
    truth = read_rgb_exr(out / "truth.exr")
    assert truth.shape == (SIZE, SIZE, 3) and np.isfinite(truth).all() and truth.max() > 0
    assert (out / "error.png").stat().st_size > 0


def test_a_directional_light_leaves_the_far_side_black(runs):
    result, out = runs["directional"]
    report = ok(result)
    assert report["lighting"]["environment"] is None and report["lighting"]["samples"] == 0
    assert report["model"]["material"] == "matte" and report["model"]["params"]["rho_s"] == [0, 0, 0]
    image = read_rgb_exr(out / "model.exr")
    # light along +x: every pixel left of the centre faces away from it
    assert (image[:, :SIZE // 2] == 0).all()
    lit = image[:, SIZE // 2:].sum(-1)
    assert (lit > 0).sum() > 0.3 * lit.size
    # Lambert: rho_d / pi · E · cos, at most 0.8 / pi · 2 where the normal points at the light
    assert image.max() == pytest.approx(0.8 / math.pi * 2, rel=0.02)
    # --force replaced the earlier file
    assert (out / "model.png").read_bytes()[:4] == b"\x89PNG"


def _one_line_error(result, *fragments):
    assert result.returncode == 2, result.stdout + result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in result.stderr, result.stderr
    assert lines[0].startswith("neuenh render: error: ")
    for fragment in fragments:
        assert fragment in lines[0], lines[0]
    assert result.stdout == ""


def test_a_bad_light_is_a_one_line_error(runs):
    result, out = runs["bad-light"]
    _one_line_error(result, "--light '1,2:3'", "x,y,z:r,g,b")
    assert not out.exists()


def test_refuses_to_overwrite_without_force(tmp_path):
    (tmp_path / "model.png").write_bytes(b"earlier")
    _one_line_error(neuenh_here("render", "--model", "ggx", *SMALL, "-o", tmp_path), "model.png", "--force")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.png"]
    assert (tmp_path / "model.png").read_bytes() == b"earlier"


@pytest.mark.parametrize("args,fragments", [
    (["--truth", "MISSING", "--model", "ggx"], ["missing.bsdf", "no such file"]),
    (["--env", "MISSING"], ["--env", "missing.bsdf", "no such file"]),
    (["--env", "FOLDER"], ["--env", "folder: not a regular file"]),
    (["--light", "0,0,0:1"], ["--light '0,0,0:1'"]),
    (["--model", "phong"], ["--model 'phong' is neither an analytical model"]),
    (["--model", "ggx", "--material", "steel"], ["--material 'steel' needs parameters"]),
    (["--truth-model", "ggx", "--truth-params", "PARAMS", "--truth-material", "steel"], ["no material 'steel'"]),
    (["--truth", "FOLDER", "--model", "ggx"], ["--truth", "not a regular file"]),  # issue 17, case 15
    (["--truth", "FIFO", "--model", "ggx"], ["--truth", "not a regular file"]),
    (["--model", "ggx", "--params", "FOLDER"], ["--params", "a folder, not a fit report", "neuenh fit -o"]),
    (["--model", "ggx", "--params", "MISSING"], ["--params", "missing.bsdf: no such file"]),
    (["--model", "ggx", "--params", "ENHANCED"], ["is a fit of ggx in state 00011100100", "the model is ggx in state "
                                                  "00000000000", "give the model it was fitted with"]),
], ids=["missing-truth", "missing-env", "env-folder", "zero-light", "unknown-model", "material-without-params", "unknown-material",
        "truth-folder", "truth-fifo", "params-folder", "params-missing", "params-of-another-model"])
def test_user_mistakes_are_one_line_errors(tmp_path, args, fragments):
    params = tmp_path / "fit.json"
    params.write_text(json.dumps({"materials": [{"name": "glossy", "params": GGX}]}))
    enhanced = tmp_path / "enhanced.json"  # `neuenh fit --json` of another state of the graph
    enhanced.write_text(json.dumps({"model": "ggx", "state": "00011100100",
                                    "materials": [{"name": "glossy", "params": GGX, "latent": [0.5] * 27}]}))
    (tmp_path / "folder").mkdir()
    os.mkfifo(tmp_path / "fifo")
    subs = {"MISSING": tmp_path / "missing.bsdf", "PARAMS": params, "FOLDER": tmp_path / "folder",
            "FIFO": tmp_path / "fifo", "ENHANCED": enhanced}
    args = [subs.get(a, a) for a in args]
    _one_line_error(neuenh_here("render", *args, *SMALL, "-o", tmp_path / "out"), *fragments)
    assert not (tmp_path / "out").exists()


def test_an_exr_environment_and_a_bundle_material(tmp_path, capsys):
    """In this process: the studio written to EXR lights exactly as the built-in one; a bundle's
    fitted material is chosen by name."""
    from neuenh_service.cli.main import main
    from neuenh.checkpoint import Bundle
    from neuenh.render import write_exr

    write_exr(tmp_path / "studio.exr", studio_environment())
    Bundle.initial("ward", ["first", "second"]).save(tmp_path / "bundle")
    common = ["--model", tmp_path / "bundle", "--material", "second", "--size", 24, "--samples", 3, "--json"]
    for env, out in (("studio", "builtin"), (tmp_path / "studio.exr", "file")):
        assert main(["render", *map(str, common), "--env", str(env), "-o", str(tmp_path / out)]) == 0
        report = json.loads(capsys.readouterr().out)
        assert report["model"]["model"] == "ward" and report["model"]["material"] == "second"
        assert report["model"]["params_from"] == f"bundle {tmp_path / 'bundle'}"
        assert report["lighting"]["environment"] == str(env)
    builtin = read_rgb_exr(tmp_path / "builtin" / "model.exr")
    assert builtin.max() > 0
    np.testing.assert_array_equal(builtin, read_rgb_exr(tmp_path / "file" / "model.exr"))


def test_params_files_pick_a_material_by_name_or_index(tmp_path):
    from neuenh.models import get_model
    from neuenh_service.cli.fit_reports import read_fit_report
    from neuenh_service.cli.render import _pick

    params = tmp_path / "fit.json"
    params.write_text(json.dumps({"materials": [{"name": "matte", "params": MATTE},
                                                {"name": "glossy", "params": GGX}]}))
    fitted = read_fit_report(params, get_model("ggx"))
    names = list(fitted)
    assert names[_pick(names, None, "")] == "matte"
    for choice in ("glossy", "1"):
        name = names[_pick(names, choice, "")]
        assert name == "glossy" and fitted[name].values["alpha_y"].tolist() == [pytest.approx(0.3)]
    with pytest.raises(ValueError, match="index 2 out of range"):
        _pick(names, "2", str(params))
    params.write_text('{"params": {}}')
    with pytest.raises(ValueError, match="neuenh fit --json"):
        read_fit_report(params, get_model("ggx"))


def test_a_material_fitted_at_an_analytical_capacity_renders_with_that_model(tmp_path):
    """`neuenh fit --capacity auto` may give a material of an enhanced model the model the search
    started from (capacity ``original``): rendered with the enhanced model, it is plain GGX with
    its parameters, image for image."""
    from neuenh.pretrained import load_model

    enhanced = load_model("enhanced-ggx", "--model")[0]
    reports = {"plain": {"model": "ggx", "state": "00000000000", "materials": [{"name": "gloss", "params": GGX}]},
               "enhanced": {"model": "ggx", "state": enhanced.state,
                            "materials": [{"name": "gloss", "params": GGX, "capacity": "original"}]}}
    images = {}
    for key, model in (("plain", "ggx"), ("enhanced", "enhanced-ggx")):
        (tmp_path / f"{key}.json").write_text(json.dumps(reports[key]))
        done = neuenh_here("render", "--model", model, "--params", tmp_path / f"{key}.json", *SMALL,
                           "-o", tmp_path / key)
        assert done.returncode == 0, done.stderr
        images[key] = read_rgb_exr(tmp_path / key / "model.exr")
    assert images["plain"].max() > 0
    np.testing.assert_array_equal(images["enhanced"], images["plain"])


def test_the_studio_environment():
    image = studio_environment()
    assert image.shape == (128, 256, 3) and image.dtype == np.float32
    assert np.isfinite(image).all() and (image > 0).all()
    np.testing.assert_array_equal(image, studio_environment())  # deterministic
    env = EnvironmentMap(image)
    key, rim = env.radiance(torch.tensor([KEY_LIGHT])), env.radiance(torch.tensor([RIM_LIGHT]))
    sky, floor = env.radiance(torch.tensor([[0.0, 1.0, 0.0]])), env.radiance(torch.tensor([[0.0, -1.0, 0.0]]))
    # the key light is the brightest thing in the map; then the rim light, the sky, the floor
    assert key.sum() >= 0.99 * float(image.sum(-1).max())
    assert key.sum() > rim.sum() > 10 * sky.sum() and sky.sum() > floor.sum()
    # most of the light the sampler picks comes from the two small discs
    directions = env.samples().direction
    near = (directions @ torch.tensor([KEY_LIGHT, RIM_LIGHT], dtype=torch.float64).T).max(1).values
    assert (near > math.cos(math.radians(12))).double().mean() > 0.3
    # another size keeps the layout
    small = studio_environment(16, 32)
    assert small.shape == (16, 32, 3) and (small > 0).all()


def test_sampling_is_chosen_and_recorded(tmp_path, capsys):
    """``--sampling light`` is the map alone: an image that differs from the MIS default (another
    estimator) and agrees with the renderer called directly with ``sampling="light"``."""
    from neuenh_service.cli.main import main
    from neuenh.models import get_model
    from neuenh.render import EnvironmentMap, model_brdf, render, sphere_scene

    for sampling in ("mis", "light"):
        assert main(["render", "--model", "ggx", "--size", "24", "--samples", "3", "--sampling", sampling,
                     "--json", "-o", str(tmp_path / sampling)]) == 0
        assert json.loads(capsys.readouterr().out)["lighting"]["sampling"] == sampling
    mis, light = (read_rgb_exr(tmp_path / s / "model.exr") for s in ("mis", "light"))
    assert np.isfinite(mis).all() and not np.array_equal(mis, light)
    from neuenh_service.cli.render import _initial_params

    model = get_model("ggx")
    direct = render(model_brdf(model, _initial_params(model)), sphere_scene(24),
                    [EnvironmentMap(studio_environment(), samples_per_axis=3, seed=0)], sampling="light")
    np.testing.assert_allclose(light, direct.numpy(), rtol=1e-3, atol=1e-6)
