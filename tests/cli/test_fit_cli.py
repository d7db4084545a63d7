"""``neuenh fit`` as a user runs it: a subprocess, exit codes, JSON, one-line errors."""

import json
import subprocess
import sys

import numpy as np
import pytest

from neuenh.checkpoint import Bundle
from neuenh.data.synthetic import synthetic_ggx
from neuenh.data.table import write_table


def neuenh(*args, timeout=120):
    return subprocess.run([sys.executable, "-m", "cli.main", *map(str, args)], capture_output=True,
                          text=True, timeout=timeout)


@pytest.fixture(scope="module")
def table(tmp_path_factory):
    (material,) = synthetic_ggx(1, seed=8, noise_sigma=0.0)
    wi, wo, f = material.samples(3000, seed=0)
    return write_table(tmp_path_factory.mktemp("t") / "steel.npz", wi, wo, f)


def test_fit_prints_json_and_writes_a_bundle(table, tmp_path):
    out = neuenh("fit", "--model", "ggx", table, "--epochs", "60", "--json", "-o", tmp_path / "b")
    assert out.returncode == 0, out.stderr
    report = json.loads(out.stdout)
    (material,) = report["materials"]
    assert material["name"] == "steel" and material["loss"] < 0.05
    assert set(material["params"]) == {"normal", "t_theta", "rho_d", "rho_s", "alpha_x", "alpha_y", "f0"}
    bundle = Bundle.load(tmp_path / "b")
    assert bundle.materials.names == ("steel",) and bundle.model.name == "ggx"


def test_fit_with_a_bundle_directory(table, tmp_path):
    from neuenh.models import get_model

    Bundle(get_model("ggx", state="00011100100", seed=0)).save(tmp_path / "enh")
    out = neuenh("fit", "--model", tmp_path / "enh", table, "--epochs", "3", "--json")
    assert out.returncode == 0, out.stderr
    report = json.loads(out.stdout)
    assert report["state"] == "00011100100" and len(report["materials"][0]["params"]["latent"]) == 27


@pytest.mark.parametrize(
    "args,message",
    [
        (["fit", "missing.npz"], "missing.npz: no such file"),
        (["fit", "--model", "phong", "TABLE"], "--model 'phong' is neither a model"),
        (["fit", "BAD"], "f_r has negative values"),
    ],
    ids=["missing-file", "unknown-model", "bad-table"],
)
def test_user_mistakes_exit_2_with_one_line(table, tmp_path, args, message):
    bad = tmp_path / "bad.npz"
    np.savez(bad, wi=[[0, 0, 1.0]], wo=[[0, 0, 1.0]], f_r=[[-1.0, 0, 0]])
    args = [str(table) if a == "TABLE" else str(bad) if a == "BAD" else a for a in args]
    out = neuenh(*args)
    assert out.returncode == 2
    assert message in out.stderr and "Traceback" not in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1


def test_usage_error_from_argparse_exits_2():
    out = neuenh("fit")
    assert out.returncode == 2 and "MEASUREMENTS" in out.stderr
