"""``neuenh export`` as a user runs it: fit a measured material with the shipped model, export it,
and run what was written in its real runtime; bad inputs are one-line errors (exit 2)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from neuenh.data.synthetic import synthetic_ggx
from neuenh.data.table import write_table
from neuenh.pretrained import bundle_path, load_model

pytestmark = pytest.mark.skipif(bundle_path("enhanced-ggx") is None, reason="no shipped models/enhanced-ggx in this tree")


def neuenh(*args, timeout=180):
    return subprocess.run([sys.executable, "-m", "cli.main", *map(str, args)], capture_output=True,
                          text=True, timeout=timeout)


def one_line_error(out, *fragments):
    assert out.returncode == 2 and "Traceback" not in out.stderr, out.stderr
    [line] = out.stderr.strip().splitlines()
    assert line.startswith("neuenh export: error: ") and all(f in line for f in fragments), line


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """A measured (synthetic GGX) material fitted with the shipped model: the report and the bundle."""
    where = tmp_path_factory.mktemp("fit")
    (material,) = synthetic_ggx(1, seed=11, noise_sigma=0.0)
    table = write_table(where / "brushed steel.npz", *material.samples(500, seed=0))
    out = neuenh("fit", "--model", "enhanced-ggx", table, "--epochs", "5", "--json", "-o", where / "bundle")
    assert out.returncode == 0, out.stderr
    (where / "fit.json").write_text(out.stdout)
    return where / "fit.json", where / "bundle"


def test_a_fit_report_exports_to_glsl_that_runs_on_llvmpipe(fitted, tmp_path):
    from gl_runtime import gl_context, run_brdf  # tests/gl_runtime.py

    report, _ = fitted
    out = neuenh("export", "enhanced-ggx", "--params", report, "--format", "glsl", "-o", tmp_path / "glsl")
    assert out.returncode == 0, out.stderr
    [path] = [Path(line) for line in out.stdout.split()]
    assert path == tmp_path / "glsl" / "brushed_steel.glsl" and path.stat().st_mode & 0o777 == 0o644

    model, _ = load_model("enhanced-ggx")
    params = {k: torch.tensor(v) for k, v in json.loads(report.read_text())["materials"][0]["params"].items()}
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
    out = neuenh("export", bundle, "--format", "glsl", "-o", tmp_path)
    assert out.returncode == 0, out.stderr
    assert [Path(p).name for p in out.stdout.split()] == ["brushed_steel.glsl"]


def test_bad_inputs_are_one_line_errors(fitted, tmp_path):
    report, bundle = fitted
    plain = tmp_path / "plain.json"
    plain.write_text(report.read_text().replace('"state": "', '"state": "x'))
    one_line_error(neuenh("export", "enhanced-ggx", "--params", plain, "--format", "glsl", "-o", tmp_path),
                   "is a fit of ggx in state x", "export the model it was fitted with")
    one_line_error(neuenh("export", bundle, "--format", "glsl", "--material", "gold", "-o", tmp_path),
                   "no material 'gold'; there are: brushed steel")
    one_line_error(neuenh("export", "ggx", "--format", "glsl", "-o", tmp_path), "ggx holds no materials")
    (tmp_path / "junk.json").write_text("{")
    one_line_error(neuenh("export", "ggx", "--params", tmp_path / "junk.json", "--format", "glsl", "-o", tmp_path),
                   "not a fit report")
    out = neuenh("export", "ggx", "--format", "mitsuba", "-o", tmp_path)
    assert out.returncode == 2 and "invalid choice: 'mitsuba'" in out.stderr
    assert list(tmp_path.glob("*.glsl")) == []  # nothing half-written
