"""``neuenh data inspect|sample|slice``: what a user sees — JSON, files written, one-line errors.

Most cases call ``cli.main.main`` in-process (fast); one runs the installed command line as a
subprocess to check exit codes and that no traceback leaks.
"""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from neuenh_service.cli.main import main
from captures import capture_directions, render_capture
from neuenh.data.param_images import write_parameter_exr
from neuenh.data.table import write_table

from data_files import RGL_DIR, hemisphere, nbrdf_weights, shared


def run(capsys, *args):
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("cli_data")
    rng = np.random.default_rng(0)
    write_table(folder / "felt.csv", hemisphere(40, 1), hemisphere(40, 2), rng.uniform(0.1, 0.5, (40, 3)),
                weight=np.full(40, 2.0))
    np.savez(folder / "nets.npz", **nbrdf_weights(["red", "blue"], seed=3))
    maps = {"rho_d": np.full((3, 5, 3), 0.3), "rho_s": np.full((3, 5, 3), 0.5), "alpha_x": np.full((3, 5), 0.2),
            "alpha_y": np.full((3, 5), 0.3), "f0": np.full((3, 5), 0.5), "normal": np.zeros((3, 5, 2)),
            "t_theta": np.zeros((3, 5))}
    render_capture(folder / "cap", maps, capture_directions(10, seed=0), name="tile")
    write_parameter_exr(folder / "params.exr", maps, metadata={"model": "ggx"})
    (folder / "spec.yaml").write_text(
        "data:\n"
        "  - {source: synthetic_zoo, materials: 2, samples: 200, seed: 1}\n"
        f"  - {{source: table, paths: ['{folder / 'felt.csv'}']}}\n"
        f"  - {{source: exr_capture, path: '{folder / 'cap'}', stride: 2}}\n"
        "val_fraction: 0.25\nseed: 3\n")
    return folder


# -- inspect ---------------------------------------------------------------------------------
def test_inspect_a_csv_table(capsys, files):
    code, out, _ = run(capsys, "data", "inspect", files / "felt.csv", "--json")
    report = json.loads(out)
    assert code == 0 and report["format"] == "table" and report["table_format"] == "csv"
    (material,) = report["materials"]
    assert material["name"] == "felt" and material["samples"] == 40 and not material["continuous"]
    assert material["weight"]["mean"] == 2.0 and 0.1 <= material["f_r"]["min"][0] <= material["f_r"]["max"][0] <= 0.5
    code, out, _ = run(capsys, "data", "inspect", files / "felt.csv")
    assert "table (csv)" in out and "40 samples" in out and "not used in training" in out


def test_inspect_nbrdf_lists_every_network(capsys, files):
    code, out, _ = run(capsys, "data", "inspect", files / "nets.npz", "--json", "--probe", "500")
    report = json.loads(out)
    assert report["format"] == "nbrdf" and [m["name"] for m in report["materials"]] == ["red", "blue"]
    assert all(m["continuous"] and m["isotropic"] and m["probe"] == 500 for m in report["materials"])


def test_inspect_a_capture_and_a_parameter_exr(capsys, files):
    code, out, _ = run(capsys, "data", "inspect", files / "cap", "--json")
    report = json.loads(out)
    assert report["format"] == "exr_capture" and report["texels"] == 15 and report["images"] == 10
    code, out, _ = run(capsys, "data", "inspect", files / "params.exr", "--json")
    report = json.loads(out)
    assert report["format"] == "parameter_exr" and report["parameters"]["rho_d"] == 3
    assert report["metadata"] == {"model": "ggx"} and "rho_d.R" in report["channels"]


def test_inspect_a_real_rgl_file(capsys):
    code, out, _ = run(capsys, "data", "inspect", shared(RGL_DIR / "paper_white_rgb.bsdf"), "--probe", "2000")
    assert code == 0 and ": rgl" in out and "paper_white_rgb: isotropic" in out and "White A4 paper" in out


# -- sample ----------------------------------------------------------------------------------
def test_sample_writes_the_arrays_and_reports_memory(capsys, files, tmp_path):
    code, out, _ = run(capsys, "data", "sample", files / "spec.yaml", "-o", tmp_path / "d.npz", "--json")
    report = json.loads(out)
    assert code == 0 and report["materials"] == 2 + 1 + 6
    with np.load(tmp_path / "d.npz") as npz:
        names = list(npz["names"])
        assert len(names) == 9 and names[2:4] == ["felt", "tile[0,0]"] and names[-1] == "tile[2,4]"
        assert npz["train_wi"].dtype == np.float32 and npz["train_material"].dtype == np.int64
        n_train, n_val = len(npz["train_wi"]), len(npz["val_f_r"])
        assert (n_train, n_val) == (report["train"], report["val"]) and n_train + n_val == 400 + 40 + 6 * 10
        assert report["memory_bytes"] == (n_train + n_val) * (3 * 3 * 4 + 8)
        assert json.loads(str(npz["recipe"]))["val_fraction"] == 0.25
    code, out, _ = run(capsys, "data", "inspect", tmp_path / "d.npz", "--json")
    assert json.loads(out)["format"] == "dataset" and json.loads(out)["train"] == report["train"]
    again = tmp_path / "again.npz"
    run(capsys, "data", "sample", files / "spec.yaml", "-o", again)
    with np.load(tmp_path / "d.npz") as a, np.load(again) as b:
        assert all(np.array_equal(a[k], b[k]) for k in a.files)


def test_sample_takes_a_whole_job_spec(capsys, tmp_path):
    spec = tmp_path / "job.yaml"
    spec.write_text("model: ggx\ntrain: {val_fraction: 0.5, seed: 2}\n"
                    "data:\n  - {source: synthetic_ggx, materials: 2, samples: 100}\n")
    code, out, _ = run(capsys, "data", "sample", spec, "-o", tmp_path / "j.npz", "--json")
    assert code == 0 and json.loads(out)["val"] == 100


# -- slice -----------------------------------------------------------------------------------
@pytest.mark.parametrize("view", ["rusinkiewicz", "hemisphere"])
def test_slice_draws_measured_next_to_a_fitted_model(capsys, files, tmp_path, view):
    png = tmp_path / f"{view}.png"
    code, out, err = run(capsys, "data", "slice", files / "nets.npz", "--material", "blue", "-o", png,
                         "--model", "ggx", "--view", view, "--resolution", "24", "--fit-samples", "400",
                         "--epochs", "5", "--json")
    assert code == 0, err
    report = json.loads(out)
    assert report["material"] == "blue" and report["model"] == "ggx" and report["fit_loss"] > 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 5000


def _ggx_report(path: Path, name: str, **params) -> Path:
    """A fit report (``neuenh fit --json``'s form) of plain GGX with one material."""
    values = {"normal": [0, 0], "t_theta": [0], "rho_d": [0.3, 0.2, 0.1], "rho_s": [0.4, 0.4, 0.4],
              "alpha_x": [0.2], "alpha_y": [0.3], "f0": [0.6], **params}
    path.write_text(json.dumps({"model": "ggx", "state": "0" * 11,
                                "materials": [{"name": name, "params": values, "capacity": "analytical"}]}))
    return path


def test_slice_draws_the_fit_a_report_holds_instead_of_fitting(capsys, files, tmp_path):
    """``--params``: the report's material of the sliced file's name, as fitted — no fit runs; another
    report's material draws another picture."""
    pictures = []
    for i, rho_d in enumerate(([0.3, 0.2, 0.1], [0.9, 0.9, 0.9])):
        png = tmp_path / f"{i}.png"
        code, out, err = run(capsys, "data", "slice", files / "nets.npz", "--material", "blue", "-o", png,
                             "--model", "ggx", "--params", _ggx_report(tmp_path / f"{i}.json", "blue", rho_d=rho_d),
                             "--resolution", "24", "--json")
        assert code == 0, err
        report = json.loads(out)
        assert report["params_from"] == str(tmp_path / f"{i}.json") and report["capacity"] == "analytical"
        assert "fit_loss" not in report and "fit_samples" not in report  # nothing was fitted
        pictures.append(png.read_bytes())
    assert pictures[0] != pictures[1]


@pytest.mark.parametrize("args, message", [
    (["--params", "REPORT"], "--params needs --model"),
    (["--model", "ggx", "--params", "OTHER"], "no material named 'blue', the sliced file's (it holds red)"),
    (["--model", "enhanced-ggx", "--params", "REPORT"], "is a fit of ggx in state 00000000000, but the model is"),
], ids=["no-model", "other-material", "other-model"])
def test_slice_params_mistakes_are_one_line(capsys, files, tmp_path, args, message):
    swap = {"REPORT": str(_ggx_report(tmp_path / "blue.json", "blue")),
            "OTHER": str(_ggx_report(tmp_path / "red.json", "red"))}
    code, out, err = run(capsys, "data", "slice", files / "nets.npz", "--material", "blue", "-o", tmp_path / "s.png",
                         *[swap.get(a, a) for a in args])
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1 and out == ""
    assert not (tmp_path / "s.png").exists()


# -- mistakes --------------------------------------------------------------------------------
@pytest.mark.parametrize("args, message", [
    (["inspect", "missing.bsdf"], "missing.bsdf: no such file"),
    (["sample", "missing.yaml", "-o", "OUT/x.npz"], "missing.yaml: no such file"),
    (["sample", "BADSPEC", "-o", "OUT/x.npz"], "invalid dataset spec: data.0.rgl.paths: Field required"),
    (["sample", "SPEC", "-o", "OUT/nowhere/x.npz"], "folder"),
    (["slice", "FILES/felt.csv", "-o", "OUT/s.png"], "a measurement table has no continuous evaluation"),
    (["slice", "FILES/cap", "-o", "OUT/s.png"], "a capture holds measured texels"),
    (["slice", "FILES/nets.npz", "-o", "OUT/s.png"], "holds 2 NBRDF networks"),
    (["slice", "FILES/nets.npz", "--material", "red", "--model", "phong", "-o", "OUT/s.png"], "--model 'phong'"),
], ids=["inspect-missing", "sample-missing", "sample-bad-spec", "sample-bad-output", "slice-table", "slice-capture",
        "slice-which-network", "slice-unknown-model"])
def test_mistakes_are_one_line_and_exit_2(capsys, files, tmp_path, args, message):
    (tmp_path / "bad.yaml").write_text("data:\n  - {source: rgl, path: x.bsdf}\n")
    swap = {"BADSPEC": str(tmp_path / "bad.yaml"), "SPEC": str(files / "spec.yaml")}
    args = [swap.get(a, a.replace("FILES", str(files)).replace("OUT", str(tmp_path))) for a in args]
    code, out, err = run(capsys, "data", *args)
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1 and out == ""


def test_the_command_line_exits_2_without_a_traceback(files, tmp_path):
    bad = tmp_path / "broken.exr"
    bad.write_bytes(b"v/1\x01" + b"\0" * 64)  # the EXR magic, then nothing usable
    out = subprocess.run([sys.executable, "-m", "neuenh_service.cli.main", "data", "inspect", str(bad)], capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 2 and out.stdout == ""
    assert out.stderr.startswith("neuenh data: error: ") and "broken.exr: not a readable OpenEXR image" in out.stderr
    assert "Traceback" not in out.stderr and len(out.stderr.strip().splitlines()) == 1
